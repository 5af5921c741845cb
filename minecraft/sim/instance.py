"""One simulated Minecraft instance's mission: its phase (dormant, loading, running,
ended), world, tick clock, frames, observations, queued commands and turn key — the
state Malmo's ``MalmoEnvServer`` keeps for its one Minecraft — and the step and peek
rules that read it. ``server.py`` owns the sockets; ``timing.py`` says how real it is.

Asynchronous missions tick every ``MsPerTick`` ms on the instance's own thread whether
or not an agent acts; commands that steps queue between two ticks all run at the next
one. Synchronous missions (MineRL's ``<StepClient>``) advance one tick per step.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

from minecraft.malmo import protocol as P
from minecraft.malmo.mission import Mission
from minecraft.sim.observe import info_json
from minecraft.sim.render import render
from minecraft.sim.session import Session
from minecraft.sim.timing import Timing
from minecraft.sim.world import World

log = logging.getLogger("graft.minecraft.server")

DORMANT, LOADING, RUNNING, ENDED = "dormant", "loading", "running", "ended"


@dataclass
class StepReply:
    """What a step hands back (before framing)."""

    frame: bytes
    reward: float
    done: bool
    sent: bool
    info: str
    turn_key: str


class Instance:
    """The mission state of one simulated Minecraft.

    Args:
        timing: real or ideal pacing.
        default_ms: tick period when the mission has no ModSettings/MsPerTick.
    """

    def __init__(self, timing: Timing, default_ms: int) -> None:
        self.timing, self.default_ms = timing, default_ms
        self.cond = threading.Condition()
        self.wake = threading.Event()  # a new phase: re-plan the tick thread
        self.phase = DORMANT
        self.world: Optional[World] = None
        self.session: Optional[Session] = None
        self.role = 0
        self.turn_handlers: frozenset[str] = frozenset()
        self.owner = -1
        self.sync = False
        self.minerl = False
        self.ms = default_ms
        self.quit = False
        self.commands: list[str] = []
        self.generation = 0
        self.loaded_at = self.run_t0 = self.ended_at = 0.0
        self.frames_taken = -1  # newest frame a step consumed
        self.info_taken = -1  # tick whose observation a step delivered
        self.turn_key = self.last_turn_key = ""
        self.tokens: dict[str, int] = {}  # Malmo's initTokens: token -> integrated port
        self.token = ""  # this instance's mission token (dropped when the mission ends)
        self._frame: tuple[int, bytes] = (-1, b"")  # (tick drawn, frame)
        self._info: tuple[int, str] = (-1, "")
        self.missions_started = 0
        self.failed = False  # the simulator raised on this mission: never draw or observe it
        self.missions_failed = 0

    # ------------------------------------------------------------------ phases
    @property
    def mission(self) -> Optional[Mission]:
        """The running (or last) mission."""
        return self.world.mission if self.world is not None else None

    @property
    def done(self) -> bool:
        """Malmo's ``envState.done``: the mission has ended."""
        return self.phase == ENDED

    def claim(self, now: float) -> Optional[str]:
        """None when a new mission may start now, else why not. Real timing only: a
        loading or running mission is also asked to quit, as Malmo's MALMOBUSY does."""
        if self.timing.ideal or self.phase == DORMANT:
            return None
        if self.phase == ENDED:
            left = self.ended_at + self.timing.ending_s - now
            if left <= 0:
                return None
            return f"busy: the previous mission is still ending ({left:.2f} s)"
        self.quit = True
        return f"busy: a mission is {self.phase}; asked it to quit"

    def start(
        self, world: World, *, owner: int, sync: bool, minerl: bool, session: Session,
        role: int, turn_handlers: frozenset[str], token: str,
    ) -> None:  # fmt: skip
        """Begin loading ``world`` (call under ``cond``; replaces any mission)."""
        if self.world is not None and not self.done:
            self.world.end("replaced by a new mission")
        now = time.monotonic()
        self.world, self.owner, self.sync, self.minerl = world, owner, sync, minerl
        self.session, self.role, self.turn_handlers = session, role, turn_handlers
        self.token = token
        self.ms = world.mission.ms_per_tick or self.default_ms
        self.phase = LOADING
        self.loaded_at = now + self.timing.loading_s
        self.quit = False
        self.commands = []
        self.frames_taken = self.info_taken = -1
        self.turn_key = self.last_turn_key = ""
        self._frame, self._info = (-1, b""), (-1, "")
        self.failed = False
        self.generation += 1
        self.missions_started += 1
        self.cond.notify_all()
        self.wake.set()

    def poll_phase(self, now: float) -> None:
        """Move loading -> running when loaded (and every agent is), and end the mission
        when its session ended for another agent, or when it waits for agents that will
        not come (call under ``cond``)."""
        if self.phase == LOADING and now >= self.loaded_at and self.session is not None:
            if self.session.loaded(self.role):
                self.phase, self.run_t0 = RUNNING, now
                self._update_turn_key()
                if self.quit:
                    self._end("quit")
                self.cond.notify_all()
            else:
                self._give_up_waiting(now)
        if self.phase == RUNNING and self.session is not None:
            reason = self.session.end_reason
            if reason is not None:
                self._end(reason)

    def _give_up_waiting(self, now: float) -> None:
        # Loaded, waiting for the other agents: a quit (role 0's connection closed, or
        # Malmo's MALMOBUSY) or another agent's end ends the mission at once, and it ends
        # after join_s whatever happens (Malmo's client waits 2,000 ticks). Otherwise one
        # client that leaves a multi-agent mission would hold this instance for good.
        assert self.session is not None
        reason = self.session.end_reason
        if reason is None and self.quit:
            reason = "quit while waiting for the other agents to join"
        if reason is None and now >= self.loaded_at + self.timing.join_s:
            reason = f"the other agents did not join within {self.timing.join_s:g} s (--join-s)"
        if reason is not None:
            self._end(reason)

    def _end(self, reason: str) -> None:
        assert self.world is not None
        self.world.end(reason)
        if self.phase == LOADING and self.role == 0 and self.session is not None:
            # Never started: the other roles' tokens go too, so a late <Find> answers 0.
            sess = self.session
            for i in range(1, sess.agent_count):
                self.tokens.pop(f"{sess.exp_uid}:{i}:{sess.reset}", None)
        self.phase, self.ended_at = ENDED, time.monotonic()
        self.tokens.pop(self.token, None)
        if self.session is not None:
            self.session.end(self.world.end_reason)
        log.info("mission ended at tick %d: %s", self.world.tick_count, self.world.end_reason)
        self.cond.notify_all()

    def fail(self, error: Exception) -> None:
        """The simulator raised on this mission: end it (only it; the next mission runs
        as usual) with the error as its end reason (call under ``cond``). Its world is
        not ticked, drawn or observed again: steps answer done with the last frame."""
        log.error("mission failed: %s", error, exc_info=error)
        if self.failed or self.world is None:
            return
        self.failed = True
        self.missions_failed += 1
        if self.phase in (LOADING, RUNNING):
            self._end(f"error: the simulator failed: {type(error).__name__}: {error}")

    def end_now(self, reason: str) -> None:
        """End the mission at once (``<Exit>``)."""
        if self.world is not None and self.phase in (LOADING, RUNNING):
            self._end(reason)

    def request_quit(self) -> bool:
        """Malmo's ``<Quit/>``: ask the mission to end; True once it has (synchronous
        missions end at once)."""
        if self.world is None or self.phase == DORMANT:
            return True
        if not self.done:
            self.quit = True
            if self.sync and self.phase == RUNNING:
                self.advance()
        return self.done

    # ------------------------------------------------------------------ ticking
    def advance(self) -> None:
        """One tick under ``cond``: apply queued commands, tick, publish. A tick that
        raises ends the mission (``fail``) instead of raising."""
        w = self.world
        assert w is not None and self.phase == RUNNING
        if self.quit:
            self._end("quit")
            return
        cmds, self.commands = self.commands, []
        try:
            with w.lock:  # the mission's agents tick one at a time in their shared world
                w.tick(self._unlock_turns(cmds) if self.turn_handlers else cmds)
            self._update_turn_key()
        except Exception as e:  # ends this mission only; the instance goes on
            self.fail(e)
            return
        if w.done:
            self._end(w.end_reason)
        self.cond.notify_all()

    def _unlock_turns(self, commands: list[str]) -> list[str]:
        """Malmo's TurnBasedCommands: a turn-based command runs only behind the current
        turn key (``"key movenorth 1"``) and uses the turn; a turn-based command without
        it is dropped; other handlers' commands pass."""
        assert self.world is not None and self.session is not None
        m = self.world.mission
        out: list[str] = []
        for cmd in commands:
            verb, _, rest = cmd.partition(" ")
            h = m.handler_for(verb)
            if h is not None:
                if h.kind not in self.turn_handlers:
                    out.append(cmd)
                continue
            lines = [c.strip() for c in rest.split("\n") if c.strip()]
            inner = m.handler_for(lines[0].split()[0]) if lines else None
            if inner is not None and inner.kind in self.turn_handlers:
                if self.session.use_turn(self.role, verb):
                    out.extend(lines)
        return out

    def _update_turn_key(self) -> None:
        # Malmo's observation(): the key in the agent's observation becomes the current
        # one unless it is the key the agent just used.
        if self.session is None or not self.turn_handlers:
            return
        turn = self.session.turn_of(self.role)
        key = turn[1] if turn is not None else ""
        if key != self.last_turn_key:
            self.turn_key = key

    def tick_due(self) -> Optional[float]:
        """Seconds until this instance's thread has something to do (0: tick on its
        clock), or None if it has nothing to do."""
        if self.phase == LOADING:
            left = self.loaded_at - time.monotonic()
            return left if left > 0 else 0.01  # waiting for the other agents
        if self.phase == RUNNING and not self.sync:
            return 0.0
        return None

    # ------------------------------------------------------------------ frames
    def _video(self) -> bool:
        m = self.mission
        return m is not None and m.has_video

    def frame_index(self, now: float) -> int:
        """The newest frame that exists (-1: none yet). Ideal timing and synchronous
        missions draw one per tick; real asynchronous missions ``fps`` per second from
        the start of the run, none without a VideoProducer, none after the end."""
        w = self.world
        if w is None or self.phase in (DORMANT, LOADING):
            return -1
        if self.timing.ideal or self.sync:
            return w.tick_count
        if not self._video():
            return -1
        t = self.ended_at if self.phase == ENDED else now
        return math.floor((t - self.run_t0) * self.timing.fps)

    def next_frame_in(self, now: float) -> float:
        """Seconds until the next real-time frame (a bound on how long to sleep)."""
        if self.phase != RUNNING or self.timing.ideal or self.sync or not self._video():
            return 0.05
        k = math.floor((now - self.run_t0) * self.timing.fps) + 1
        return max(0.0, self.run_t0 + k / self.timing.fps - now) + 1e-4

    def frame_ready(self) -> bool:
        """A frame no step has consumed yet exists."""
        return self.frame_index(time.monotonic()) > self.frames_taken

    def frame_bytes(self) -> bytes:
        """The newest frame (b"" without a VideoProducer). The world changes only at
        ticks, so frames between two ticks are the same picture: drawn once per tick."""
        w = self.world
        if w is None or not self._video():
            return b""
        key = w.tick_count
        if self._frame[0] != key and not self.failed:
            m = w.mission
            with w.lock:
                self._frame = (key, render(w, m.width, m.height, depth=m.want_depth))
        return self._frame[1]

    # ------------------------------------------------------------------ info
    def _observation(self) -> str:
        w = self.world
        assert w is not None
        if self._info[0] != w.tick_count and not self.failed:
            with w.lock:
                text = info_json(w)
            turn = self.session.turn_of(self.role) if self.turn_handlers and self.session else None
            if turn is not None:
                extra = f'"turn_number":{turn[0]},"turn_key":"{turn[1]}"'
                text = "{" + extra + ("," + text[1:] if len(text) > 2 else "}")
            self._info = (w.tick_count, text)
        return self._info[1]

    def info_ready(self) -> bool:
        """An observation to deliver exists: MineRL repeats the latest; otherwise one no
        step delivered yet (real Malmo sends the first at the first tick, and none when
        it would be ``{}``)."""
        w = self.world
        if w is None or self.phase in (DORMANT, LOADING):
            return False
        if self.minerl:
            return True
        if self.timing.ideal:
            return w.tick_count > self.info_taken
        return w.tick_count >= 1 and w.tick_count > self.info_taken and self._observation() != "{}"

    def take_info(self) -> str:
        """The observation to deliver, or "" (and mark it delivered)."""
        if not self.info_ready():
            return ""
        assert self.world is not None
        self.info_taken = self.world.tick_count
        return self._observation()

    # ------------------------------------------------------------------ waiting
    def wait(self, ready: Callable[[], bool], seconds: float) -> bool:
        """Wait under ``cond`` until ``ready()`` or ``seconds`` pass (frames appear with
        time, so sleep no longer than to the next one)."""
        deadline = time.monotonic() + seconds
        while not ready():
            now = time.monotonic()
            if now >= deadline:
                return False
            self.cond.wait(min(deadline - now, self.next_frame_in(now)))
            self.poll_phase(time.monotonic())
        return True

    # ------------------------------------------------------------------ requests
    def step(self, commands: list[str], *, with_info: bool, step_key: str) -> StepReply:
        """Malmo's asynchronous ``<StepN>`` (call under ``cond``): take the newest frame
        (waiting up to ``wait_s`` for one); queue the commands when there is a frame and
        it is the agent's turn (Malmo's turn-key table); then collect rewards and info."""
        t = self.timing
        if not self.done and not self.frame_ready():
            self.wait(lambda: self.frame_ready() or self.done, t.wait_s)
        done = self.done
        have = self.frame_ready()
        index = self.frame_index(time.monotonic())
        frame = self.frame_bytes() if have else b""
        sent, next_key = False, self.turn_key
        if not done and have:
            if not self.turn_key:
                if not step_key:
                    self.commands.extend(commands)
                    sent = True
                else:
                    next_key = step_key
            elif step_key == self.turn_key:
                self.commands.append(step_key + " " + "\n".join(commands))
                self.turn_key, self.last_turn_key = "", step_key
                sent = True
        reward, info = 0.0, ""
        if done or sent:
            w = self.world
            if w is not None:
                reward, w.pending_reward = w.pending_reward, 0.0
            if with_info:
                info = self.take_info()
                if not info and not done and not t.ideal:
                    # Malmo waits for the next observation, and takes a later frame.
                    self.wait(
                        lambda: self.info_ready() or self.done or self._later(index), t.wait_s
                    )
                    info = self.take_info()
                    if have and self._later(index):
                        index = self.frame_index(time.monotonic())
                        frame = self.frame_bytes()
            if have:
                self.frames_taken = index
        return StepReply(frame, reward, done, sent, info, next_key)

    def _later(self, index: int) -> bool:
        return self.frame_index(time.monotonic()) > index

    def step_sync(self, commands: list[str], *, with_info: bool) -> StepReply:
        """MineRL's ``<StepClientN>``: queue, advance one tick, reply (under ``cond``).

        Raises:
            ProtocolError: real timing and no VideoProducer (MineRL's server has no frame
                to send and drops the connection).
        """
        if self.phase == LOADING:
            self.wait(lambda: self.phase != LOADING, self.timing.loading_s + self.timing.wait_s)
        if not self.timing.ideal and self.world is not None and not self._video():
            raise P.ProtocolError("MineRL's server has no frame to send without a VideoProducer")
        self.commands.extend(commands)
        if self.phase == RUNNING:
            self.advance()
        w = self.world
        reward = 0.0
        if w is not None:
            reward, w.pending_reward = w.pending_reward, 0.0
        info = self.take_info() if with_info and w is not None else ""
        frame = self.frame_bytes()
        return StepReply(frame, reward, self.done, True, info, "")

    def peek(self) -> tuple[bytes, str, bool]:
        """``<Peek/>``: the newest frame without consuming it, the latest observation (for
        MineRL's reply) and done (under ``cond``). Malmo waits up to ``wait_s`` for a
        frame; MineRL blocks until the mission has loaded."""
        t = self.timing
        if self.minerl and self.phase == LOADING:
            self.wait(lambda: self.phase != LOADING, t.loading_s + t.wait_s)
            if not t.ideal and self.world is not None and not self._video():
                raise P.ProtocolError(
                    "MineRL's server has no frame to send without a VideoProducer"
                )
        if not self.done and not self.frame_ready():
            self.wait(lambda: self.frame_ready() or self.done, t.wait_s)
        index = self.frame_index(time.monotonic())
        frame = self.frame_bytes() if index > self.frames_taken else b""
        info = self._observation() if self.minerl and self.phase in (RUNNING, ENDED) else ""
        return frame, info, self.done
