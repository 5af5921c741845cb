"""Helpers shared by the learner tests: a fixed-output "network" and a small TD3 setup."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner

OBS_DIM, ACT_DIM = 3, 2
LOW = np.array([-1.0, 0.0], dtype=np.float32)
HIGH = np.array([3.0, 1.0], dtype=np.float32)
SMALL = TD3Config(hidden_sizes=(16, 16))


class Table(nn.Module):
    """A "network" that returns fixed rows (one row: the same for every input)."""

    def __init__(self, rows: list[list[float]]) -> None:
        super().__init__()
        self.rows = torch.tensor(rows)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if len(self.rows) == 1:
            return self.rows[0].expand(*obs.shape[:-1], -1)
        return self.rows


class FixedRows:
    """An acting "network" as actors hold one (numpy): returns fixed rows (one row: the
    same for every input), keeps the last input in `seen`; `load` takes {"rows": ...}."""

    def __init__(self, rows: list[list[float]]) -> None:
        self.rows = np.asarray(rows, np.float32)
        self.seen = np.zeros(0, np.float32)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.seen = np.array(x, copy=True)
        if len(self.rows) == 1:
            return np.broadcast_to(self.rows[0], (*x.shape[:-1], self.rows.shape[1])).copy()
        return self.rows.copy()

    def load(self, weights: dict[str, np.ndarray]) -> None:
        self.rows = np.asarray(weights["rows"], np.float32)


def td3_batch(n: int = 32, seed: int = 0) -> dict[str, torch.Tensor]:
    """A random TD3 batch over OBS_DIM / ACT_DIM, actions partly outside [LOW, HIGH]."""
    g = torch.Generator().manual_seed(seed)
    return {
        "obs": torch.randn(n, OBS_DIM, generator=g),
        "action": 3 * torch.randn(n, ACT_DIM, generator=g),  # unclipped, partly out of box
        "reward": torch.randn(n, generator=g),
        "terminated": torch.rand(n, generator=g) < 0.2,
        "truncated": torch.rand(n, generator=g) < 0.2,
        "next_obs": torch.randn(n, OBS_DIM, generator=g),
        "log_prob": torch.randn(n, generator=g),
        "policy_version": torch.zeros(n, dtype=torch.int64),
    }


def td3_learner(config: TD3Config = SMALL, seed: int = 0) -> TD3Learner:
    return TD3Learner(OBS_DIM, ACT_DIM, LOW, HIGH, config=config, seed=seed)


def flat_params(module: nn.Module) -> torch.Tensor:
    """Every parameter of ``module`` in one flat tensor (to compare before and after)."""
    return torch.cat([p.detach().flatten() for p in module.parameters()])
