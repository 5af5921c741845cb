"""The behaviour policy a Minecraft actor acts with, and the log-likelihood it records.

Until the learner's first weights arrive the actor moves uniformly at random over the
action box (policy version -1); afterwards it acts with the broadcast TD3 actor network
plus Gaussian exploration noise. Either way it returns the *unclipped* sampled action and
that action's log-likelihood under the behaviour policy: importance ratios are taken on
the unclipped sampled action (the clipped one has a point mass at the bounds).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Optional

import numpy as np
import torch

from actors.minecraft.encoding import ACTION_SPACE
from actors.policies import GaussianExploration, UniformRandomPolicy
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from learner.td3.networks import Actor

RANDOM_VERSION = -1
"""The policy version recorded for the uniform random warm-up policy."""


class MinecraftBehaviour:
    """Uniform random until weights are loaded, then TD3's actor + N(0, σ²) noise.

    Args:
        obs_dim: size of the encoded observation.
        td3: supplies the network architecture and ``exploration_noise`` (fraction of
            the largest action).
    """

    def __init__(self, obs_dim: int, td3: TD3Config) -> None:
        self.low = np.asarray(ACTION_SPACE.low, dtype=np.float32)
        self.high = np.asarray(ACTION_SPACE.high, dtype=np.float32)
        self._obs_dim, self._td3 = obs_dim, td3
        self.uniform = UniformRandomPolicy(self.low, self.high)
        max_action = float(np.max(np.abs(self.high)))
        self.exploration = GaussianExploration(
            td3.exploration_noise * max_action, self.low, self.high
        )
        self.network: Optional[Actor] = None
        self.version = RANDOM_VERSION

    def load(self, weights: Mapping[str, torch.Tensor], version: int) -> None:
        """Adopt a policy (a ``TD3Learner.policy_state()``) published as ``version``."""
        if self.network is None:
            self.network = make_actor_network(
                self._obs_dim, len(self.low), self.low, self.high, self._td3
            )
            self.network.eval()
        self.network.load_state_dict(weights)
        self.version = version

    def follow(self, network: Actor, version: int) -> None:
        """Act with a live network trained in this process (the naive loop's own learner)."""
        self.network, self.version = network, version

    def act(self, obs: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float, int]:
        """Sample an action for one observation.

        Returns:
            ``(action, log_prob, version)``: the unclipped float32 action [A], its
            log-likelihood under the behaviour policy, and the policy version.
        """
        if self.network is None:
            action, log_prob = self.uniform.sample(1, rng)
            return action[0], float(log_prob[0]), RANDOM_VERSION
        with torch.no_grad():
            mean = self.network(torch.as_tensor(obs, dtype=torch.float32)[None]).numpy()[0]
        action, log_prob = self.exploration.sample(mean, rng)
        return action, float(log_prob), self.version
