"""A stand-in environment for throughput tuning: a preset's spaces, a chosen cost per step.

`SimulatedEnv` has the observation and action spaces of the task it stands in for, so an
`EnvActor` stepping it with the preset's own behaviour writes exactly the preset's
transitions (columns, dtypes, shapes, log-likelihoods, policy versions) through the real
insert path and weight subscription; only the environment's dynamics are fake. Each step
costs what it is told to::

    busy-wait cpu_ms           the client's own CPU work (decoding an observation, ...)
    sleep latency_ms           waiting on something else (a network round trip, ...)
    pace to steps_per_s        a rate cap (0: as fast as possible)
    real time, tick_ms         a world clock ticking on its own: a step waits for the
                               next tick and reports it as info["tick"], so the actor's
                               `TickMeter` counts the ticks it was too slow to see

    EnvSpec("actors.simulated:SimulatedEnv", simulated_env_kwargs(env, cpu_ms=2.0, tick_ms=50))
"""

from __future__ import annotations

import time
from typing import Any, Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

ENV_ID = "actors.simulated:SimulatedEnv"
POOL = 16
"""Distinct observations an environment cycles through (drawn once: stepping is free)."""


def busy_wait(seconds: float) -> None:
    """Spends `seconds` of this thread's CPU time (a stand-in for real work: on a busy
    machine it takes longer, as the work would)."""
    if seconds <= 0:
        return
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def simulated_env_kwargs(
    env: gym.Env,
    *,
    cpu_ms: float = 0.0,
    latency_ms: float = 0.0,
    steps_per_s: float = 0.0,
    tick_ms: float = 0.0,
    episode_steps: Optional[int] = None,
) -> dict[str, Any]:
    """`SimulatedEnv`'s keyword arguments standing in for `env` (its spaces, its episode
    limit unless `episode_steps` is given), with the given cost per step."""
    if episode_steps is None:
        spec = getattr(env, "spec", None)
        episode_steps = (spec.max_episode_steps if spec is not None else None) or 1000
    return {
        "observation_space": env.observation_space,
        "action_space": env.action_space,
        "cpu_ms": cpu_ms,
        "latency_ms": latency_ms,
        "steps_per_s": steps_per_s,
        "tick_ms": tick_ms,
        "episode_steps": episode_steps,
    }


class SimulatedEnv(gym.Env):
    """An environment with given spaces whose steps cost a chosen CPU time and latency.

    Args:
        observation_space: the stood-in task's observation space (a Box).
        action_space: its action space (any; actions are ignored).
        cpu_ms: CPU busy-waited per step.
        latency_ms: time slept per step.
        steps_per_s: the most steps per second this environment takes (0: no cap).
        tick_ms: real-time mode: the world ticks every `tick_ms` on its own (0: off).
        episode_steps: steps per episode (truncated at the end).
        seed: seeds the observation pool and rewards.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(
        self,
        *,
        observation_space: spaces.Box,
        action_space: spaces.Space[Any],
        cpu_ms: float = 0.0,
        latency_ms: float = 0.0,
        steps_per_s: float = 0.0,
        tick_ms: float = 0.0,
        episode_steps: int = 1000,
        seed: int = 0,
    ) -> None:
        for name, value in (
            ("cpu_ms", cpu_ms),
            ("latency_ms", latency_ms),
            ("steps_per_s", steps_per_s),
            ("tick_ms", tick_ms),
        ):
            if not value >= 0:
                raise ValueError(f"{name}={value} must be >= 0")
        if episode_steps < 1:
            raise ValueError(f"episode_steps={episode_steps} must be >= 1")
        if not isinstance(observation_space, spaces.Box):
            raise ValueError(f"observation_space must be a Box, got {observation_space}")
        self.observation_space = observation_space
        self.action_space = action_space
        self.cpu_s, self.latency_s = cpu_ms / 1000, latency_ms / 1000
        self.period_s = 1.0 / steps_per_s if steps_per_s else 0.0
        self.tick_s = tick_ms / 1000
        self.episode_steps = episode_steps
        rng = np.random.default_rng(seed)
        low = np.where(np.isfinite(observation_space.low), observation_space.low, -1.0)
        high = np.where(np.isfinite(observation_space.high), observation_space.high, 1.0)
        shape = (POOL, *observation_space.shape)
        self._pool = rng.uniform(low, high, shape).astype(observation_space.dtype)
        self._rewards = rng.standard_normal(POOL).astype(np.float32)
        self._t = 0
        self._steps = 0
        self._next_step = 0.0  # earliest start of the next step under steps_per_s
        self._clock0 = time.monotonic()
        self._tick = -1

    def _world_tick(self) -> int:
        return int((time.monotonic() - self._clock0) / self.tick_s)

    def _next_tick(self) -> int:
        """Waits for a tick newer than the last one seen; returns the newest."""
        now = self._world_tick()
        if now <= self._tick:
            time.sleep(max(self._clock0 + (self._tick + 1) * self.tick_s - time.monotonic(), 0))
            now = max(self._world_tick(), self._tick + 1)
        self._tick = now
        return now

    def _info(self) -> dict[str, Any]:
        return {"tick": self._next_tick()} if self.tick_s else {}

    def reset(
        self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._steps = 0
        return self._pool[self._t % POOL], self._info()

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        busy_wait(self.cpu_s)
        if self.latency_s:
            time.sleep(self.latency_s)
        if self.period_s:
            now = time.monotonic()
            if now < self._next_step:
                time.sleep(self._next_step - now)
            self._next_step = max(now, self._next_step) + self.period_s
        info = self._info()
        self._t += 1
        self._steps += 1
        truncated = self._steps >= self.episode_steps
        return (
            self._pool[self._t % POOL],
            float(self._rewards[self._t % POOL]),
            False,
            truncated,
            info,
        )
