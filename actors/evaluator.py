"""Ray actor that evaluates published policy weights with deterministic episodes."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import ray
import torch

from actors.evaluation import run_episodes
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config


@ray.remote(num_cpus=0.25)
class Evaluator:
    """Runs `episodes` deterministic episodes of the acting network (no exploration noise)."""

    def __init__(self, *, env_id: str, td3: TD3Config, seed: int) -> None:
        torch.set_num_threads(1)
        env = gym.make(env_id)
        space = env.action_space
        self.env_id, self.seed = env_id, seed
        self.network = make_actor_network(
            env.observation_space.shape[0], space.shape[0], space.low, space.high, td3
        )
        self.network.eval()

    def evaluate(self, weights: dict[str, Any], *, episodes: int, tag: Any = None) -> dict[str, Any]:
        """Returns mean and std of the episode returns, echoing `tag` back."""
        self.network.load_state_dict(weights)

        def policy(obs: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                return self.network(torch.as_tensor(obs, dtype=torch.float32)).numpy()

        returns = run_episodes(policy, env_id=self.env_id, episodes=episodes, seed=self.seed)
        return {"tag": tag, "mean": float(returns.mean()), "std": float(returns.std())}
