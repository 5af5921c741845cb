"""The travel task as a gymnasium environment over MalmoEnv, for the service's actors.

``gym.make("minecraft.agent.travel_env:MinecraftTravel-v0")`` imports this module (so
Ray workers register it themselves). Each environment talks to its world only through
graft's MalmoEnv client over a socket, synchronous (`ticks_per_step` ticks per step, 1
by default) or in real time. Given an ``address`` it plays the Minecraft there (a real
one, or a simulated world server); without one it starts its own simulated server (on a
free loopback port, in a thread of the same process). The simulator is named by import
strings (``world_server``, ``terrain``) resolved only when used, so this module runs
without ``minecraft.sim`` when given an address and its missions.

Per step::

    action a = μ(s) + clip(π(s)) (composed by the behaviour; clipped to [−1, 1] here)
    reply = client.step(move a0, strafe a1, turn a2, jump [a3 > 0], the tree's pitch)
    p' = parse(reply.info); φ' = route_to_go(route, p')
    r = (φ − φ') − tick_cost − stuck_penalty·[stuck]           (travel_task.TravelReward)
    μ(s'), next cell = tree(p')                                (travel_control.TreeSteering)
    s' = observation(p', μ(s'), ...)

An episode terminates on arrival (feet in the destination cell) or death, and is
truncated at ``max_ticks``. ``reset(seed=...)`` seeds the choice of missions: a world
from ``world_seeds`` and a destination in its terrain (``travel_task.draw_missions``).
"""

from __future__ import annotations

import dataclasses
import importlib
import random
from collections.abc import Callable
from typing import Any, Optional, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from minecraft.agent.leaves.percept import Percept, parse
from minecraft.agent.travel_control import (
    ACTION_NAMES,
    MU,
    OBS_DIM,
    STUCK,
    TreeSteering,
    compose_commands,
    observation,
)
from minecraft.agent.travel_task import (
    RewardConfig,
    TerrainSource,
    TravelMission,
    TravelReward,
    draw_missions,
    route_to_go,
    travel_mission_xml,
)
from minecraft.malmo.client import MalmoClient

ENV_ID = "minecraft.agent.travel_env:MinecraftTravel-v0"
TRAIN_WORLDS = tuple(range(1000, 1064))
"""Worlds training draws from; bench/travel.py evaluates on worlds 0.. (disjoint)."""
MAX_TICKS = 600
SIM_WORLD_SERVER = "minecraft.sim.server:WorldServer"
"""The simulated world server, started when no address is given."""
SIM_TERRAIN = "minecraft.sim.worldgen:generate"
"""The simulator's terrain of a world seed, which missions are drawn from."""


class LocalWorldServer(Protocol):
    """A world server the environment runs itself (the simulator's ``WorldServer``)."""

    def start(self) -> int:
        """Start serving; returns the port."""
        ...

    def stop(self) -> None:
        """Stop serving and close every connection."""
        ...


class WorldLink:
    """An environment's way to its world: a Malmo client to `address`, or, when that is
    None, to a world server (`world_server`, an import string, resolved here so that a bad
    one fails at once) it starts in-process on first use. `close` ends both."""

    def __init__(self, address: Optional[str], world_server: str, *, synchronous: bool) -> None:
        self._new_server: Optional[Callable[..., LocalWorldServer]] = (
            load(world_server) if address is None else None
        )
        self.address, self.synchronous = address, synchronous
        self._server: Optional[LocalWorldServer] = None
        self.client: Optional[MalmoClient] = None

    def connect(self) -> MalmoClient:
        """The client, connecting (and starting the server) the first time."""
        if self.client is None:
            if self._new_server is not None:
                self._server = self._new_server(port=0)
                host, port = "127.0.0.1", self._server.start()
            else:
                assert self.address is not None
                host, _, p = self.address.rpartition(":")
                port = int(p)
            self.client = MalmoClient(host, port, synchronous=self.synchronous, timeout=30.0)
        return self.client

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        if self._server is not None:
            self._server.stop()
            self._server = None


def load(spec: str) -> Any:
    """The object an import string ``"package.module:name"`` names.

    Raises:
        ValueError: ``spec`` is not of that form, or its module has no such name.
    """
    module, sep, name = spec.partition(":")
    if not sep or not module or not name:
        raise ValueError(f"{spec!r} is not an import string 'package.module:name'")
    obj = getattr(importlib.import_module(module), name, None)
    if obj is None:
        raise ValueError(f"{spec!r}: module {module} has no {name}")
    return obj


class TravelBackbone:
    """μ(s) for the backbone and options methods: the tree's steering, which the
    environment computed and put in the observation (``travel_control.MU``). The presets
    name it ``hardcoded_policy: minecraft.agent.travel_env:TravelBackbone``."""

    batched = True
    """It reads μ(s) off every row of a batch at once."""

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.array(np.asarray(obs)[..., MU], dtype=np.float32)


def correction_trusted(obs: np.ndarray, *, stalled: float = 0.5) -> np.ndarray:
    """The tree's recovery rule for a learned correction: once ``stalled`` · K ticks passed
    without progress (half the stuck rule's K by default), the tree drops the correction
    and steers alone until progress resumes. [B] bool, from the observation's counter."""
    return np.asarray(obs)[..., STUCK] < stalled


def reward_config(reward: Optional[RewardConfig | dict[str, Any]]) -> RewardConfig:
    """``reward`` as a RewardConfig (None: the defaults; a mapping: those fields changed)."""
    if reward is None:
        return RewardConfig()
    if isinstance(reward, RewardConfig):
        return reward
    fields = [f.name for f in dataclasses.fields(RewardConfig)]
    unknown = sorted(set(reward) - set(fields))
    if unknown:
        raise ValueError(f"reward: unknown fields {unknown}; the fields are {fields}")
    return RewardConfig(**reward)


class MinecraftTravelEnv(gym.Env):
    """Travel to a destination in a seeded world with continuous movement commands.

    Args:
        address: ``host:port`` of a running Minecraft or world server; None starts
            ``world_server`` in-process.
        world_seeds: worlds to draw missions from.
        missions: a fixed list of missions, played in order (cycling); overrides
            ``world_seeds`` (the benchmark's fixed set).
        world_server: import string of the server started when ``address`` is None,
            called with ``port=0`` (a ``LocalWorldServer``).
        terrain: import string of the function giving a world seed's terrain
            (``travel_task.TerrainSource``) that missions are drawn from; unused when
            ``missions`` are given.
        max_ticks: ticks before the episode is truncated.
        reward: the reward's weights and the stuck rule, or a mapping of some of its fields
            (a run's ``--set 'env_kwargs.reward={tick_cost: 0.1}'``).
        real_time: Malmo's asynchronous mode: the world ticks every 50 ms whether or not
            the agent acts, a step's commands run at the next tick and its reply is the
            latest observation (False: synchronous, deterministic).
        ticks_per_step: synchronous mode: ticks each step advances, its commands held
            (Malmo's continuous commands persist) and the frames between unseen: a slow
            client, deterministically (a real-time client deciding every k-th tick).
            The step ends early on arrival or death.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        *,
        address: Optional[str] = None,
        world_seeds: tuple[int, ...] = TRAIN_WORLDS,
        missions: Optional[list[TravelMission]] = None,
        max_ticks: int = MAX_TICKS,
        reward: Optional[RewardConfig | dict[str, Any]] = None,
        real_time: bool = False,
        ticks_per_step: int = 1,
        world_server: str = SIM_WORLD_SERVER,
        terrain: str = SIM_TERRAIN,
    ) -> None:
        if max_ticks < 1:
            raise ValueError(f"max_ticks={max_ticks} must be >= 1")
        if ticks_per_step < 1:
            raise ValueError(f"ticks_per_step={ticks_per_step} must be >= 1")
        if real_time and ticks_per_step > 1:
            raise ValueError(
                f"ticks_per_step={ticks_per_step} needs the synchronous world: in real time "
                "the world decides how many ticks pass between steps"
            )
        if not world_seeds and not missions:
            raise ValueError("world_seeds is empty and no missions were given: nothing to play")
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(len(ACTION_NAMES),), dtype=np.float32)
        self.address = address
        self.world_seeds = tuple(world_seeds)
        self.fixed = list(missions) if missions else None
        self.max_ticks = max_ticks
        self.real_time = real_time
        self.ticks_per_step = ticks_per_step
        self.reward_fn = TravelReward(reward_config(reward))
        self.steering = TreeSteering()
        self._world = WorldLink(address, world_server, synchronous=not real_time)
        # Resolved here, only when it will be used: a bad import string fails at once.
        self._terrain_of: Optional[TerrainSource] = None if missions else load(terrain)
        self._rng = random.Random(0)
        self._played = 0
        self.mission: Optional[TravelMission] = None
        self._percept: Optional[Percept] = None
        self._waypoint: Optional[tuple[int, int, int]] = None
        self._pitch = 0.0
        self._ticks = 0

    # ------------------------------------------------------------------ plumbing
    def _next_mission(self) -> TravelMission:
        if self.fixed is not None:
            m = self.fixed[self._played % len(self.fixed)]
        else:
            assert self._terrain_of is not None
            world = self._rng.choice(self.world_seeds)
            m = draw_missions(world, 1, self._rng, terrain=self._terrain_of(world))[0]
        self._played += 1
        return m

    def _observe(self, p: Percept, elapsed: int = 1) -> np.ndarray:
        assert self.mission is not None
        mu, self._waypoint = self.steering(p, self.mission.route)
        self._pitch = self.steering.ctx.commands.pitch
        stuck = self.reward_fn.stuck
        obs = observation(
            p,
            mu=mu,
            waypoint=self._waypoint,
            destination=self.mission.destination,
            previous=(self._percept.x, self._percept.y, self._percept.z) if self._percept else None,
            stuck_fraction=stuck.ticks_without_progress / stuck.ticks,
            elapsed=elapsed,
        )
        self._percept = p
        return obs

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self._rng = random.Random(seed)
            self._played = 0 if self.fixed is None else seed
        client = self._world.connect()
        self.mission = self._next_mission()
        client.init(travel_mission_xml(self.mission, time_limit_ticks=self.max_ticks + 20))
        client.reset()
        reply = client.observe()  # real Malmo may answer a step without info
        if not reply.info:
            raise RuntimeError("the travel mission ended before its first observation")
        p = parse(reply.info)
        self.steering.reset()
        self.reward_fn.reset(route_to_go(self.mission.route, p.x, p.y, p.z))
        self._percept, self._ticks = None, 0
        obs = self._observe(p)
        return obs, {"phi": self.reward_fn.phi, "tick": p.tick}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        client = self._world.client
        assert self.mission is not None and client is not None
        reply = client.step(compose_commands(action, self._pitch))
        for _ in range(self.ticks_per_step - 1):  # hold the commands, unseen frames
            if reply.done or not reply.info or self._ended(parse(reply.info)):
                break
            reply = client.step("")
        prev = self._percept
        assert prev is not None
        p = parse(reply.info) if reply.info else prev
        # Game ticks since the last observation: ticks_per_step in synchronous mode (fewer
        # on arrival); in real time as many as passed (the skipped ones cost time too).
        elapsed = max(1, p.tick - prev.tick)
        self._ticks += elapsed
        phi = route_to_go(self.mission.route, p.x, p.y, p.z)
        reward, stuck = self.reward_fn.step(phi, ticks=elapsed)
        arrived = p.cell == self.mission.destination
        died = bool(reply.info) and not p.alive
        terminated = arrived or died or (reply.done and not reply.info)
        truncated = not terminated and (self._ticks >= self.max_ticks or reply.done)
        obs = self._observe(p, elapsed)
        info = {
            "phi": phi,
            "stuck": stuck,
            "stuck_events": self.reward_fn.stuck.events,
            "arrived": arrived,
            "died": died,
            "ticks": self._ticks,
        }
        if reply.info:
            info["tick"] = p.tick  # the world's clock: an actor meters the ticks skipped
        return obs, float(reward), bool(terminated), bool(truncated), info

    def _ended(self, p: Percept) -> bool:
        assert self.mission is not None
        return p.cell == self.mission.destination or not p.alive

    def close(self) -> None:
        self.steering.close()
        self._world.close()


gym.register(id="MinecraftTravel-v0", entry_point=f"{__name__}:MinecraftTravelEnv")
