"""Ray actor stepping several gymnasium environments with the current behaviour policy.

It streams transitions (with the behaviour log-likelihood and policy version) to the
replay server and adopts newer weights whenever the learner publishes them. What it
acts with is a `Behaviour` (service/core.py); the actor itself knows no algorithm.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import ray
import torch

from actors.task import EnvSpec
from service.core import Behaviour, ReplayWriter, WeightSource


class VectorStepper:
    """Steps `n` environments side by side; resets each one when its episode ends.

    Unlike gymnasium's vector autoreset, `next_obs` is always the true successor of
    `obs` (the final observation of an episode, never the first of the next one).
    """

    def __init__(self, env: EnvSpec, n: int, seed: int) -> None:
        self.envs = [env.make() for _ in range(n)]
        self.obs = np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(self.envs)])
        self.episode_returns = np.zeros(n)
        self.finished_returns: list[float] = []

    def step(self, actions: np.ndarray) -> dict[str, np.ndarray]:
        obs = self.obs.copy()
        next_obs = np.empty_like(obs)
        rewards = np.empty(len(self.envs), np.float32)
        terminated = np.empty(len(self.envs), bool)
        truncated = np.empty(len(self.envs), bool)
        for i, env in enumerate(self.envs):
            next_obs[i], rewards[i], terminated[i], truncated[i], _ = env.step(actions[i])
            self.episode_returns[i] += rewards[i]
            if terminated[i] or truncated[i]:
                self.finished_returns.append(float(self.episode_returns[i]))
                self.episode_returns[i] = 0.0
                self.obs[i] = env.reset()[0]
            else:
                self.obs[i] = next_obs[i]
        return {
            "obs": obs.astype(np.float32),
            "reward": rewards,
            "terminated": terminated,
            "truncated": truncated,
            "next_obs": next_obs.astype(np.float32),
        }


@dataclass(frozen=True)
class Segment:
    """A stretch of one actor's work: `steps` transitions into `table`, the first
    `warmup_steps` of them with the behaviour's warm-up policy."""

    table: str
    steps: int
    warmup_steps: int = 0


@ray.remote(num_cpus=0.25)
class EnvActor:
    """Collects transitions segment by segment with its behaviour policy."""

    def __init__(
        self,
        *,
        env: EnvSpec,
        num_envs: int,
        seed: int,
        replay: ReplayWriter,
        weights: WeightSource,
        behaviour: Behaviour,
        steps_per_insert: int,
    ) -> None:
        torch.set_num_threads(1)
        self.stepper = VectorStepper(env, num_envs, seed)
        self.rng = np.random.default_rng(seed)
        self.replay = replay
        self.weights = weights
        self.behaviour = behaviour
        self.steps_per_insert = steps_per_insert
        self.versions_seen: list[int] = []
        self.stats: list[dict[str, float]] = []

    def _adopt_new_weights(self, block_s: float = 0.0) -> None:
        weights = self.weights.poll(block_s=block_s)
        if weights is not None:
            self.behaviour.load(weights)
            self.versions_seen.append(self.weights.version)

    def _wait_for_first_weights(self) -> None:
        """Blocks until the learner publishes (it may pre-train first) or says stop."""
        while self.weights.version < 0 and not self.weights.stopped:
            self._adopt_new_weights(block_s=5.0)

    def run(self, segments: list[Segment]) -> dict[str, Any]:
        """Steps through `segments` in order (or until the learner says stop)."""
        n = len(self.stepper.envs)
        done_steps, insert_wait_s, start = 0, 0.0, time.perf_counter()
        for segment in segments:
            buffer: list[dict[str, np.ndarray]] = []
            seg_steps = 0
            while seg_steps < segment.steps and not self.weights.stopped:
                warmup = seg_steps < segment.warmup_steps
                if not warmup:
                    self._wait_for_first_weights()
                self._adopt_new_weights()
                env_action, record = self.behaviour.act(self.stepper.obs, self.rng, warmup=warmup)
                record.update(self.stepper.step(env_action))
                # Columns computed on s' (e.g. the backbone's μ(s')); most add none.
                record.update(self.behaviour.next_columns(record["next_obs"]))
                self.behaviour.end_episodes(record["terminated"] | record["truncated"])
                version = -1 if warmup else self.weights.version  # -1: the warm-up policy
                record["policy_version"] = np.full(n, version, np.int64)
                # Each environment is one stream: the table links its steps into episodes,
                # so sampled windows never mix environments or cross an episode end.
                record["_stream"] = np.arange(n, dtype=np.int64)
                buffer.append(record)
                seg_steps += n
                if len(buffer) >= self.steps_per_insert or seg_steps >= segment.steps:
                    batch = {k: np.concatenate([r[k] for r in buffer]) for k in buffer[0]}
                    t = time.perf_counter()
                    self.replay.insert(segment.table, batch)
                    insert_wait_s += time.perf_counter() - t
                    buffer.clear()
                    if stats := self.behaviour.stats():
                        self.stats.append({"actor_steps": done_steps + seg_steps, **stats})
            done_steps += seg_steps
        return {
            "env_steps": done_steps,
            "wall_s": time.perf_counter() - start,
            "insert_s": insert_wait_s,
            "versions_seen": self.versions_seen,
            "episode_returns": self.stepper.finished_returns,
            "behaviour_stats": self.stats,
        }
