"""The paper's naive loop, kept only for the decoupling comparison of ``bench/minecraft_suite.py``:
the acting process trains its own TD3 between two steps (sec. IV-D: "the slower and
heavier execution of the RL training makes it skipping too many useful frames"). graft's
actors never do this.

One client of the naive loop, per world step::

    action = π(s) + N(0, σ²)          (uniform random before the first update)
    s', r, ... = env.step(action)      (real time: the world ticks on meanwhile)
    trainer.add(s, a, r, s');  trainer.train()      # inside the acting loop

It steps its environment through the actor's ``VectorStepper``, so its skipped ticks and
own step latency are metered exactly as graft's actors' are.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Mapping
from typing import Any, Optional

import numpy as np
import torch

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import VectorStepper
from actors.task import EnvSpec
from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner
from minecraft.agent.mission_env import ACTION_SPACE


class InlineTrainer:
    """A private ring buffer and a TD3 learner living inside one actor.

    Args:
        obs_dim: encoded observation size.
        td3: hyper-parameters (``batch_size`` is the update's batch).
        seed: seeds the networks and the buffer sampling.
        updates_per_step: TD3 updates after every environment step.
        capacity: ring buffer size (transitions).
        learning_starts: transitions in the buffer before the first update.
    """

    def __init__(
        self,
        obs_dim: int,
        *,
        td3: TD3Config,
        seed: int,
        updates_per_step: int = 1,
        capacity: int = 100_000,
        learning_starts: int = 256,
    ) -> None:
        if updates_per_step < 1:
            raise ValueError(
                f"updates_per_step={updates_per_step} must be >= 1; without updates use "
                "graft's decoupled actors instead of the naive loop"
            )
        if not 0 < learning_starts <= capacity:
            raise ValueError(f"learning_starts={learning_starts} must lie in (0, {capacity}]")
        act_dim = ACTION_SPACE.shape[0]
        self.learner = TD3Learner(
            obs_dim, act_dim, ACTION_SPACE.low, ACTION_SPACE.high, config=td3, seed=seed
        )
        self.batch_size, self.updates_per_step = td3.batch_size, updates_per_step
        self.capacity, self.learning_starts = capacity, learning_starts
        self.rng = np.random.default_rng(seed)
        self.size = self._next = 0
        self.columns = {
            "obs": np.zeros((capacity, obs_dim), np.float32),
            "action": np.zeros((capacity, act_dim), np.float32),
            "reward": np.zeros(capacity, np.float32),
            "terminated": np.zeros(capacity, bool),
            "next_obs": np.zeros((capacity, obs_dim), np.float32),
        }

    def add(self, record: Mapping[str, np.ndarray]) -> None:
        """Store one transition (columns beyond TD3's needs are ignored)."""
        for k, col in self.columns.items():
            col[self._next] = record[k]
        self._next = (self._next + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)

    def train(self) -> int:
        """Run ``updates_per_step`` TD3 updates (none before ``learning_starts``)."""
        if self.size < self.learning_starts:
            return 0
        for _ in range(self.updates_per_step):
            idx = self.rng.integers(0, self.size, self.batch_size)
            self.learner.update({k: torch.from_numpy(c[idx]) for k, c in self.columns.items()})
        return self.updates_per_step

    @property
    def num_updates(self) -> int:
        return self.learner.num_updates


class _LiveNetwork:
    """Acts with the very torch network the trainer updates (no published copy)."""

    def __init__(self, network: torch.nn.Module) -> None:
        self.network = network

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.network(torch.as_tensor(obs, dtype=torch.float32)).numpy()

    def load(self, weights: Mapping[str, np.ndarray]) -> None:
        raise AssertionError("the naive loop's network is trained in place, never loaded")


class NaiveLoop:
    """One client of the naive loop: acts with the TD3 actor it trains between steps.

    Args:
        env_id: the environment (a real-time Minecraft mission for the benchmark).
        env_kwargs: its keyword arguments.
        td3: network architecture, exploration noise and update hyper-parameters.
        seed: seeds the environment, the exploration and the learner.
        updates_per_step: TD3 updates after every step.
        learning_starts: transitions stored before the first update.
        nice: the acting thread's CPU niceness, as for graft's actors (None: leave it).
    """

    def __init__(
        self,
        *,
        env_id: str,
        env_kwargs: dict[str, Any],
        td3: TD3Config,
        seed: int,
        updates_per_step: int = 1,
        learning_starts: int = 256,
        nice: Optional[int] = 0,
    ) -> None:
        torch.set_num_threads(1)
        self.stepper = VectorStepper(EnvSpec(env_id, env_kwargs), 1, seed)
        obs_dim = self.stepper.obs.shape[1]
        self.trainer = InlineTrainer(
            obs_dim,
            td3=td3,
            seed=seed,
            updates_per_step=updates_per_step,
            learning_starts=learning_starts,
        )
        low, high = ACTION_SPACE.low, ACTION_SPACE.high
        # The behaviour acts with the very network the trainer updates.
        self.behaviour = GaussianBehaviour(
            _LiveNetwork(self.trainer.learner.actor), std=td3.exploration_noise, low=low, high=high
        )
        self.rng = np.random.default_rng(seed)
        self.nice = nice
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)
        self.steps = 0
        self._stop = threading.Event()
        self._window = (time.monotonic(), 0)

    def stop(self) -> None:
        """Ask a running ``run()`` to return after its current step."""
        self._stop.set()

    def restart_meters(self) -> None:
        """Start a new measurement window (ticks skipped, latency, rates)."""
        self.stepper.meter.restart()
        self._window = (time.monotonic(), self.steps)

    def run(
        self,
        *,
        duration_s: Optional[float] = None,
        max_steps: Optional[int] = None,
        measure_after_s: float = 0.0,
    ) -> dict[str, Any]:
        """Act and train until ``duration_s`` passed, ``max_steps`` steps were taken or
        ``stop()`` was called; restart the meters ``measure_after_s`` after starting.

        Raises:
            ValueError: neither budget was given (the loop would never end).
        """
        if duration_s is None and max_steps is None:
            raise ValueError("give duration_s or max_steps: run() would never return")
        if self.nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)  # this (acting) thread only
            except OSError:
                pass  # not permitted: `actor/nice` shows what the loop got
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)
        self._stop.clear()
        start = time.monotonic()
        deadline = start + duration_s if duration_s is not None else float("inf")
        last_step = self.steps + max_steps if max_steps is not None else None
        warming = measure_after_s > 0
        self.restart_meters()
        while not self._stop.is_set() and time.monotonic() < deadline:
            if last_step is not None and self.steps >= last_step:
                break
            if warming and time.monotonic() - start >= measure_after_s:
                self.restart_meters()
                warming = False
            self._step()
        return self.report()

    def _step(self) -> None:
        warmup = self.trainer.num_updates == 0
        env_action, columns = self.behaviour.act(self.stepper.obs, self.rng, warmup=warmup)
        record = {**columns, **self.stepper.step(env_action)}
        if self.stepper.lost[0]:
            return  # the world went away mid-step: no transition
        self.steps += 1
        self.trainer.add({k: v[0] for k, v in record.items()})
        self.trainer.train()  # the naive loop: training inside the acting loop

    def report(self) -> dict[str, Any]:
        """Counters and rates of the current measurement window (as graft's actors')."""
        t0, steps0 = self._window
        wall = max(time.monotonic() - t0, 1e-9)
        meter = self.stepper.meter.metrics()
        out: dict[str, Any] = {
            "actor/env_steps": self.steps,
            "actor/nice": self.acting_nice,
            "perf/measure_s": wall,
            "perf/steps_per_s": (self.steps - steps0) / wall,
            **meter,
            "net/connection_losses": self.stepper.connection_losses,
            "policy/version": self.trainer.num_updates,
            "learner/inline_updates": self.trainer.num_updates,
        }
        if "perf/ticks_seen" in meter:
            ticks = meter["perf/ticks_seen"] + meter["perf/ticks_skipped"]
            out["perf/world_ticks_per_s"] = ticks / wall
        return out

    def close(self) -> None:
        self.stepper.close()
