"""Deterministic evaluation: the mean-return figures of the paper and the Ray actor that
scores published weights with them.

Episodes are stepped side by side in plain gymnasium environments with our own loop
(no vector-env autoreset), so episode ``i`` is always seeded with ``seed + i`` and its
return does not depend on how many environments run at once.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, Optional

import gymnasium as gym
import numpy as np
import ray
import torch
from ray import ObjectRef

from actors.policies import UniformRandomPolicy
from service.core import Behaviour, EvalTag, Evaluation, Weights

Policy = Callable[[np.ndarray], np.ndarray]
"""A batched policy: observations [B, *obs_shape] -> actions [B, *action_shape]."""


def run_episodes(
    policy: Policy,
    *,
    env_id: str = "Pendulum-v1",
    episodes: int = 100,
    seed: int = 0,
    num_envs: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> np.ndarray:
    """Runs full episodes and returns their undiscounted returns.

    Each step calls ``policy`` once on the observations of all running environments.
    An episode ends on termination or truncation (time limit); a finished environment
    starts the next pending episode.

    Args:
        policy: Batched policy; called with [B, *obs_shape], must return [B, ...].
        env_id: Gymnasium environment id.
        episodes: Number of episodes to run.
        seed: Episode ``i`` is reset with ``seed + i``.
        num_envs: Environments stepped side by side; all ``episodes`` at once when None.
        env_kwargs: Keyword arguments for ``gym.make`` (the run config's ``env_kwargs``).

    Returns:
        float64 returns of shape [episodes], in episode order.

    Raises:
        ValueError: If ``episodes`` or ``num_envs`` is not positive, or the policy
            returns the wrong batch size.
    """
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")
    num_envs = episodes if num_envs is None else num_envs
    if num_envs < 1:
        raise ValueError(f"num_envs={num_envs} must be >= 1")
    num_envs = min(num_envs, episodes)

    envs = [gym.make(env_id, **(env_kwargs or {})) for _ in range(num_envs)]
    returns = np.zeros(episodes, dtype=np.float64)
    episode_of = list(range(num_envs))  # episode each env is running; -1 when idle
    obs = [envs[k].reset(seed=seed + k)[0] for k in range(num_envs)]
    next_episode = num_envs
    try:
        while True:
            running = [k for k in range(num_envs) if episode_of[k] >= 0]
            if not running:
                break
            actions = np.asarray(policy(np.stack([obs[k] for k in running])))
            if actions.shape[0] != len(running):
                raise ValueError(
                    f"policy returned {actions.shape[0]} actions for {len(running)} observations"
                )
            for action, k in zip(actions, running, strict=True):
                obs[k], reward, terminated, truncated, _ = envs[k].step(action)
                returns[episode_of[k]] += float(reward)
                if terminated or truncated:
                    if next_episode < episodes:
                        episode_of[k] = next_episode
                        obs[k] = envs[k].reset(seed=seed + next_episode)[0]
                        next_episode += 1
                    else:
                        episode_of[k] = -1
    finally:
        for env in envs:
            env.close()
    return returns


def random_policy_for(env_id: str, *, seed: int = 0) -> Policy:
    """Returns a uniform random batched policy over an environment's Box action space.

    Args:
        env_id: Gymnasium environment id with a bounded ``Box`` action space.
        seed: Seed of the policy's own random generator.

    Returns:
        A policy mapping [B, *obs_shape] to float32 actions [B, *action_shape].

    Raises:
        ValueError: If the action space is not a bounded Box.
    """
    env = gym.make(env_id)
    space = env.action_space
    env.close()
    if not isinstance(space, gym.spaces.Box):
        raise ValueError(f"{env_id} has action space {space}; random_policy_for needs a Box")
    uniform = UniformRandomPolicy(space.low.reshape(-1), space.high.reshape(-1))
    rng = np.random.default_rng(seed)

    def policy(obs: np.ndarray) -> np.ndarray:
        action, _ = uniform.sample(len(obs), rng)
        return action.reshape(len(obs), *space.shape)

    return policy


@ray.remote(num_cpus=0.25)
class Evaluator:
    """Runs `episodes` deterministic episodes of a behaviour's greedy policy (no exploration)."""

    def __init__(
        self,
        *,
        env_id: str,
        behaviour: Behaviour,
        seed: int,
        env_kwargs: Optional[dict[str, Any]] = None,
    ) -> None:
        torch.set_num_threads(1)
        self.env_id, self.seed, self.env_kwargs = env_id, seed, env_kwargs
        self.behaviour = behaviour

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Evaluation:
        """Returns mean and std of the episode returns, echoing `tag` back.

        `stats` carries what the behaviour counted while acting greedily (e.g. how often
        each option ran).
        """
        self.behaviour.load(weights)
        self.behaviour.stats()  # drop anything counted before these weights
        returns = run_episodes(
            self.behaviour.greedy,
            env_id=self.env_id,
            episodes=episodes,
            seed=self.seed,
            env_kwargs=self.env_kwargs,
        )
        return {
            "tag": tag,
            "mean": float(returns.mean()),
            "std": float(returns.std()),
            "stats": self.behaviour.stats(),
        }


class RemoteEvaluator:
    """The learner's `Evaluator` (service/core.py): an `Evaluator` Ray actor runs the episodes."""

    def __init__(
        self,
        *,
        env_id: str,
        behaviour: Behaviour,
        seed: int,
        env_kwargs: Optional[dict[str, Any]] = None,
    ) -> None:
        # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
        self._actor = Evaluator.remote(  # type: ignore[attr-defined]
            env_id=env_id, behaviour=behaviour, seed=seed, env_kwargs=env_kwargs
        )

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Future[Evaluation]:
        """Starts the episodes in the actor and returns at once."""
        ref: ObjectRef[Evaluation] = self._actor.evaluate.remote(
            weights, episodes=episodes, tag=tag
        )
        return ref.future()
