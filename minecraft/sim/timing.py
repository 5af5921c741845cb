"""How a simulated Minecraft instance paces a mission: like a real Malmo client (the
default) or the convenient "ideal" way tests and benchmarks may ask for.

Real (what ``launchClient.sh -env`` does, read from Malmo's ``MalmoEnvServer.java`` and
``ClientStateMachine.java``):

* a MissionInit is answered 0 (busy) while a mission is loading, running or ending; a
  running one is asked to quit, as Malmo's ``MALMOBUSY`` does;
* a new mission loads for ``loading_s`` before its first frame and tick; a Peek or step
  meanwhile waits up to ``wait_s`` and gets an empty frame (sent = 0);
* an ended mission takes ``ending_s`` before the instance is free again;
* a multi-agent mission whose other roles have not all joined ``join_s`` after role 0
  loaded ends (Malmo's client gives up after 2,000 client ticks, about 100 s); it ends
  at once when role 0's connection closes while it waits;
* frames come at ``fps`` whatever the tick rate; a step takes the newest frame (waiting
  for the next one if it already took it), and its info is empty when no tick produced
  an observation since the last step;
* without a VideoProducer no frame ever comes: each step waits ``wait_s`` and reports
  sent = 0, so its commands are never queued.

Ideal (graft's convenience, ``--ideal``): no loading or ending delay, a new MissionInit
replaces the running mission, one frame per tick (a step waits for the next tick), info
with every frame, and commands are queued without a VideoProducer.
"""

from __future__ import annotations

from dataclasses import dataclass

WAIT_S = 3.0  # Malmo's COND_WAIT_SECONDS
JOIN_S = 100.0  # Malmo's ClientStateMachine waits 2,000 client ticks of 50 ms for the others


@dataclass(frozen=True)
class Timing:
    """Pacing of one simulated Minecraft instance.

    Attributes:
        ideal: graft's convenient pacing instead of real Malmo's (see the module doc).
        loading_s: seconds from an accepted MissionInit to the first frame and tick.
        ending_s: seconds from a mission's end until a new MissionInit is accepted.
        fps: frames per second while a mission runs (independent of the tick rate).
        wait_s: the longest a Peek or step waits for a frame or an observation.
        join_s: seconds a multi-agent mission waits, once role 0 has loaded, for the
            other roles to join and load before it ends (either timing).
    """

    ideal: bool = False
    loading_s: float = 1.0
    ending_s: float = 0.5
    fps: float = 60.0
    wait_s: float = WAIT_S
    join_s: float = JOIN_S

    def __post_init__(self) -> None:
        for name in ("loading_s", "ending_s", "wait_s", "join_s"):
            v = getattr(self, name)
            if not v >= 0.0:
                raise ValueError(f"Timing.{name} must be >= 0 seconds, got {v}")
        if not self.fps > 0.0:
            raise ValueError(f"Timing.fps must be positive, got {self.fps}")

    @property
    def mode(self) -> str:
        """``"ideal"`` or ``"real"``."""
        return "ideal" if self.ideal else "real"


REAL = Timing()
IDEAL = Timing(ideal=True, loading_s=0.0, ending_s=0.0)
