"""The paper's naive loop, kept for comparison: the acting process trains its own TD3
between two steps (sec. IV-D: "the slower and heavier execution of the RL training makes
it skipping too many useful frames"). graft's actors never do this; ``bench/minecraft.py``
measures what it costs.

    trainer = InlineTrainer(obs_dim, act_dim, td3=td3, seed=0, updates_per_step=1)
    loop:  step the world;  trainer.add(transition);  trainer.train()   # inside the loop
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from actors.minecraft.encoding import ACTION_SPACE
from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner


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
