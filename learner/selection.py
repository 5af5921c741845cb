"""The final selection: at the end of a run, keep the learned policy only if it beat the
hard-coded one on training-side evaluation episodes, else fall back to the tree.

`LearnerLoop.run` scores both on the evaluator's episodes (its reset seeds, never the
held-out ones a benchmark tests on) and calls `keep_tree` when `tree_wins` says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from actors.behaviours.switching import TREE_ONLY
from service.core import Weights


@dataclass(frozen=True)
class SelectionConfig:
    """The final selection between the learned policy and the tree (0 episodes: none)."""

    episodes: int = 0
    """Evaluation episodes each of the two is scored on at the end (0: no selection, the
    learned policy is kept as it is)."""
    z: float = 1.0
    """The learned policy is kept only if its mean gain over the tree, episode by episode
    on the same starts, exceeds z standard errors of that gain (a one-sided paired test;
    0: any gain)."""

    def __post_init__(self) -> None:
        if self.episodes < 0:
            raise ValueError(f"episodes={self.episodes} must be >= 0 (0: no final selection)")
        if self.episodes == 1:
            raise ValueError("episodes=1 gives no spread to compare by: use 0 (none) or >= 2")
        if not (math.isfinite(self.z) and self.z >= 0.0):
            raise ValueError(f"z={self.z} must be a finite number >= 0 (standard errors)")


def tree_wins(policy_returns: Sequence[float], tree_returns: Sequence[float], *, z: float) -> bool:
    """True unless the learned policy's gain over the tree, d_i = R_π(i) − R_μ(i) on the
    same episode starts i, has mean(d) > z · std(d) / √n (sample std): a paired one-sided
    test, far sharper than comparing the two means apart, since the same start makes both
    returns high or low together. Ties keep the tree.

    Raises:
        ValueError: the two are not scored on the same ≥ 2 episodes.
    """
    if len(policy_returns) != len(tree_returns) or len(policy_returns) < 2:
        raise ValueError(
            f"paired selection needs the same >= 2 episodes for both, got "
            f"{len(policy_returns)} and {len(tree_returns)}"
        )
    gains = np.asarray(policy_returns, dtype=np.float64) - np.asarray(tree_returns)
    error = float(gains.std(ddof=1)) / math.sqrt(len(gains))
    return not float(gains.mean()) > z * error


def with_tree_only(weights: Weights, tree_only: bool) -> Weights:
    """`weights`, plus the ``TREE_ONLY`` entry when the greedy policy is μ alone (absent
    otherwise, so that a learner which never falls back publishes what it always did)."""
    import torch  # the config reads SelectionConfig from here before anything loads torch

    return {**weights, TREE_ONLY: torch.tensor(1.0)} if tree_only else weights
