"""Ray actor stepping several gymnasium environments with the current behaviour policy.

It streams transitions (with the behaviour log-likelihood and policy version) to the
replay server and adopts newer weights whenever the learner publishes them.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
import ray
import torch

from actors.policies import GaussianExploration, UniformRandomPolicy
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from service.client import ReplayClient
from service.weights import WeightSubscriber


class VectorStepper:
    """Steps `n` environments side by side; resets each one when its episode ends.

    Unlike gymnasium's vector autoreset, `next_obs` is always the true successor of
    `obs` (the final observation of an episode, never the first of the next one).
    """

    def __init__(self, env_id: str, n: int, seed: int) -> None:
        self.envs = [gym.make(env_id) for _ in range(n)]
        self.obs = np.stack([env.reset(seed=seed + i)[0] for i, env in enumerate(self.envs)])
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


@ray.remote(num_cpus=0.25)
class EnvActor:
    """Collects `num_steps` transitions: uniform-random for the first `random_steps`,
    then the broadcast TD3 actor plus Gaussian exploration noise."""

    def __init__(
        self,
        *,
        env_id: str,
        num_envs: int,
        seed: int,
        replay: ReplayClient,
        table: str,
        broadcaster: Any,
        td3: TD3Config,
        steps_per_insert: int,
    ) -> None:
        torch.set_num_threads(1)
        self.stepper = VectorStepper(env_id, num_envs, seed)
        space = self.stepper.envs[0].action_space
        self.low, self.high = space.low, space.high
        self.rng = np.random.default_rng(seed)
        self.replay, self.table = replay, table
        self.weights = WeightSubscriber(broadcaster)
        obs_dim = self.stepper.envs[0].observation_space.shape[0]
        self.network = make_actor_network(obs_dim, space.shape[0], self.low, self.high, td3)
        self.network.eval()
        max_action = float(np.max(np.abs(self.high)))
        self.exploration = GaussianExploration(td3.exploration_noise * max_action, self.low, self.high)
        self.uniform = UniformRandomPolicy(self.low, self.high)
        self.steps_per_insert = steps_per_insert
        self.versions_seen: list[int] = []

    def _adopt_new_weights(self, block_s: float = 0.0) -> None:
        weights = self.weights.poll(block_s=block_s)
        if weights is not None:
            self.network.load_state_dict(weights)
            self.versions_seen.append(self.weights.version)

    def _act(self, obs: np.ndarray, random: bool) -> tuple[np.ndarray, np.ndarray, int]:
        if random:
            action, log_prob = self.uniform.sample(len(obs), self.rng)
            return action, log_prob, -1  # version -1: the uniform warm-up policy
        with torch.no_grad():
            mean = self.network(torch.as_tensor(obs, dtype=torch.float32)).numpy()
        action, log_prob = self.exploration.sample(mean, self.rng)
        return action, log_prob, self.weights.version

    def run(self, num_steps: int, random_steps: int) -> dict[str, Any]:
        """Steps until `num_steps` transitions were inserted (or the learner says stop)."""
        n = len(self.stepper.envs)
        buffer: list[dict[str, np.ndarray]] = []
        done_steps, insert_wait_s, start = 0, 0.0, time.perf_counter()
        while done_steps < num_steps and not self.weights.stopped:
            if self.weights.version < 0 and done_steps >= random_steps:
                self._adopt_new_weights(block_s=60.0)  # the learner publishes version 0 at start
            else:
                self._adopt_new_weights()
            action, log_prob, version = self._act(self.stepper.obs, done_steps < random_steps)
            record = self.stepper.step(np.clip(action, self.low, self.high))
            record["action"] = action.astype(np.float32)
            record["log_prob"] = log_prob.astype(np.float32)
            record["policy_version"] = np.full(n, version, np.int64)
            buffer.append(record)
            done_steps += n
            if len(buffer) >= self.steps_per_insert or done_steps >= num_steps:
                batch = {k: np.concatenate([r[k] for r in buffer]) for k in buffer[0]}
                t = time.perf_counter()
                self.replay.insert(self.table, batch)
                insert_wait_s += time.perf_counter() - t
                buffer.clear()
        return {
            "env_steps": done_steps,
            "wall_s": time.perf_counter() - start,
            "insert_s": insert_wait_s,
            "versions_seen": self.versions_seen,
            "episode_returns": self.stepper.finished_returns,
        }
