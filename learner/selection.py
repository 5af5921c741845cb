"""The final selection: at the end of a run, keep the learned policy only if it beat the
hard-coded one on training-side evaluation episodes, else fall back to the tree.

`LearnerLoop.run` scores both on the evaluator's episodes (its reset seeds, never the
held-out ones a benchmark tests on) and calls `keep_tree` when `tree_wins` says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class SelectionConfig:
    """The final selection between the learned policy and the tree (0 episodes: none)."""

    episodes: int = 0
    """Evaluation episodes each of the two is scored on at the end (0: no selection, the
    learned policy is kept as it is)."""
    z: float = 1.0
    """The learned policy is kept only if its mean return beats the tree's by more than z
    standard errors of the difference, √((σ_π² + σ_μ²) / n) (a one-sided test; 0: any gain)."""

    def __post_init__(self) -> None:
        if self.episodes < 0:
            raise ValueError(f"episodes={self.episodes} must be >= 0 (0: no final selection)")
        if self.episodes == 1:
            raise ValueError("episodes=1 gives no spread to compare by: use 0 (none) or >= 2")
        if not (math.isfinite(self.z) and self.z >= 0.0):
            raise ValueError(f"z={self.z} must be a finite number >= 0 (standard errors)")


def tree_wins(
    *,
    policy_mean: float,
    policy_std: float,
    tree_mean: float,
    tree_std: float,
    episodes: int,
    z: float,
) -> bool:
    """True unless the learned policy's mean beats the tree's by more than z standard errors.

    The two are scored on the same episodes, but the difference's error is taken as if they
    were independent, √((σ_π² + σ_μ²) / n): an upper bound while their returns correlate
    positively, as the same starts make them do. Ties keep the tree.
    """
    error = math.sqrt((policy_std**2 + tree_std**2) / episodes)
    return not policy_mean - tree_mean > z * error
