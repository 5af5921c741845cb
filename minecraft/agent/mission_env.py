"""Any Malmo mission as a gymnasium environment over MalmoEnv: the paper's observation
vector in, continuous movement commands out, real time by default.

``gym.make("minecraft.agent.mission_env:MinecraftMission-v0", address=...,
mission_xml=..., max_episode_steps=600)`` connects to a world server (graft's simulator
or a real Malmo Minecraft) and plays the mission there::

    obs = encode(reset().info)                      # ConnectionError: the world is away
    reply = client.step(commands(clip(action)))     # between two ticks: then observe()
    next_obs = encode(reply.info); info["tick"] = reply.info["TotalTime"]

* Observation: the sec. III-D vector of ``grid_encoding`` without item slots (position,
  orientation, life and food, the mission's grid as {0, 1} occupancy). The mission needs
  ObservationFromFullStats and exactly one ObservationFromGrid grid.
* Action: the box ``[-1, 1]^6``: move, strafe, turn, pitch (ContinuousMovementCommands
  speeds), then jump and attack, on when their component is positive. The environment
  clips; the actor stores the unclipped action.
* Timing (Malmo's): a step's commands apply at the world's next tick. Frames come
  faster than ticks, so a step that lands between two ticks waits for that tick's
  observation (the reply then shows the commands' effect); a step after a tick it has
  not seen gets that observation at once (the effect shows one observation later, as
  in ``malmoenv``). Continuous commands persist. ``info["tick"]`` is the world's clock,
  so an actor meters the ticks it skipped.
* Endings: death or a mission goal (``AgentQuitFrom...``) terminates; the mission's time
  limit truncates (so does gymnasium's ``max_episode_steps``).
* A world server that goes away (refused, reset, closed, hung) raises
  ``ConnectionError`` from ``step`` or ``reset``; the next ``reset`` reconnects.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from minecraft.agent import grid_encoding
from minecraft.malmo import protocol as P
from minecraft.malmo.client import MalmoClient, StepResult
from minecraft.malmo.mission import Mission, parse_mission

ENV_ID = "minecraft.agent.mission_env:MinecraftMission-v0"
ACTION_NAMES = ("move", "strafe", "turn", "pitch", "jump", "attack")
ACTION_SPACE = spaces.Box(-1.0, 1.0, shape=(len(ACTION_NAMES),), dtype=np.float32)
MS_PER_GAME_TICK = 50  # game time, whatever the server's real-time tick length

# What a world server going away looks like from the client (refused, reset, closed, hung).
_LOST = (OSError, P.ProtocolError)


def _cells(mission: Mission) -> int:
    (g,) = mission.grids
    return math.prod(h - lo + 1 for lo, h in zip(g.lo, g.hi, strict=True))


def observation_space(mission: Mission, k: int = 0) -> spaces.Box:
    """The encoded observation's space for ``mission`` with ``k`` item slots.

    Raises:
        ValueError: the mission lacks ObservationFromFullStats or has not exactly one
            ObservationFromGrid grid, which the encoding reads.
    """
    if not mission.full_stats:
        raise ValueError(
            "the mission has no <ObservationFromFullStats/>: the encoding needs position, "
            "orientation, life, food and TotalTime (to count skipped ticks)"
        )
    if len(mission.grids) != 1:
        raise ValueError(
            f"the mission has {len(mission.grids)} ObservationFromGrid grids; the encoding "
            "reads exactly one (the cube around the agent): add one <Grid> or merge them"
        )
    size = grid_encoding.size(k, _cells(mission))
    return spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)


def encode_observation(info: Mapping[str, Any], mission: Mission, k: int = 0) -> np.ndarray:
    """One step's info JSON (already decoded) -> the float32 observation vector.

    Args:
        info: the merged observation producers of one step.
        mission: the mission the info comes from (names the grid and entity range).
        k: nearest dropped items to include (``grid_encoding``'s item slots).

    Returns:
        A vector of ``observation_space(mission, k).shape``.

    Raises:
        KeyError: a stat or the grid is missing from ``info``.
        ValueError: the grid has the wrong number of cells.
    """
    grid = mission.grids[0].name
    cells = _cells(mission)
    if len(info[grid]) != cells:
        raise ValueError(f"grid {grid!r} has {len(info[grid])} cells, the mission says {cells}")
    entities = mission.nearby[0].name if mission.nearby else "entities"
    return grid_encoding.encode(info, k=k, grid=grid, entities=entities)


def action_commands(action: np.ndarray) -> str:
    """A (possibly unclipped) action -> newline-joined ContinuousMovementCommands."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return (
        f"move {a[0]:.3f}\nstrafe {a[1]:.3f}\nturn {a[2]:.3f}\npitch {a[3]:.3f}\n"
        f"jump {int(a[4] > 0)}\nattack {int(a[5] > 0)}"
    )


class MissionEnv(gym.Env):
    """One Minecraft client playing ``mission_xml`` on the world server at ``address``.

    Args:
        address: ``host:port`` of the world server.
        mission_xml: the mission (needs ObservationFromFullStats and one grid).
        real_time: Malmo's asynchronous mode, the world ticking on its own (False:
            MineRL's synchronous mode, one tick per step).
        world_seed: ask graft's server for this world seed; None for a real Malmo.
        timeout_s: socket timeout; a world silent this long counts as gone.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        *,
        address: str,
        mission_xml: str,
        real_time: bool = True,
        world_seed: Optional[int] = None,
        timeout_s: float = 10.0,
    ) -> None:
        self.mission = parse_mission(mission_xml)
        self.observation_space = observation_space(self.mission)
        self.action_space = ACTION_SPACE
        host, _, port = address.rpartition(":")
        self.client = MalmoClient(
            host,
            int(port),
            synchronous=not real_time,
            seed=world_seed,
            timeout=timeout_s,
            connect_attempts=1,
            info_decoder=grid_encoding.GridInfo(self.mission.grids[0].name),
        )
        self.client.init(mission_xml)
        self._obs: Optional[np.ndarray] = None
        self._tick = 0

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        try:
            self.client.reset()
            first = self.client.observe()  # real Malmo: steps may bring no observation yet
            if first.done or not first.info:
                raise P.ProtocolError("the new mission ended before its first observation")
        except _LOST as e:
            self.client.close()
            raise ConnectionError(f"world server {self._address}: {type(e).__name__}: {e}") from e
        self._obs = encode_observation(first.info, self.mission)
        self._tick = int(first.info["TotalTime"])
        return self._obs, {"tick": self._tick}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        assert self._obs is not None, "call reset() first"
        try:
            reply = self.client.step(action_commands(action))
            if not reply.info and not reply.done:
                # Between two ticks (frames come faster than ticks): the step's commands
                # apply at the next tick, so this transition ends at that tick's
                # observation, not at a frame of the same world state.
                later = self.client.observe()
                later.reward += reply.reward
                reply = later
        except _LOST as e:
            self.client.close()
            self._obs = None
            raise ConnectionError(f"world server {self._address}: {type(e).__name__}: {e}") from e
        info: dict[str, Any] = {}
        if reply.info:
            self._obs = encode_observation(reply.info, self.mission)
            self._tick = int(reply.info["TotalTime"])
            info["tick"] = self._tick
        # else the mission ended between ticks: no newer observation exists
        terminated, truncated = self._ending(reply)
        return self._obs, float(reply.reward), terminated, truncated, info

    def _ending(self, reply: StepResult) -> tuple[bool, bool]:
        """(terminated, truncated): death or a mission goal terminates; the mission's
        time limit truncates (truncation is not termination: the learner still
        bootstraps through it)."""
        if not reply.done:
            return False, False
        if reply.info and not reply.info.get("IsAlive", True):
            return True, False  # died
        limit_ms = self.mission.time_limit_ms
        tick = self._tick if reply.info else self._tick + 1  # ended between two ticks
        if limit_ms is not None and tick * MS_PER_GAME_TICK >= limit_ms:
            return False, True  # ServerQuitFromTimeUp
        return True, False  # an AgentQuitFrom... goal, or the agent quit

    @property
    def _address(self) -> str:
        return f"{self.client.host}:{self.client.port}"

    def close(self) -> None:
        self.client.close()


gym.register(id="MinecraftMission-v0", entry_point=f"{__name__}:MissionEnv")
