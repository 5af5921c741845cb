"""The final selection: at the end of a run, keep the learned policy only if it beat the
hard-coded one on training-side evaluation episodes, else fall back to the tree.

`LearnerLoop.run` scores both on the evaluator's episodes (its reset seeds, never the
held-out ones a benchmark tests on) and calls `keep_tree` when `tree_wins` says so. With
``best_in_run`` the policy of the run's best in-run evaluation is a second candidate
(`choose`): π often peaks before the end of a short budget and falls back (Hopper).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from statistics import NormalDist
from typing import Optional

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
    best_in_run: bool = False
    """Also a candidate: the policy of the run's best in-run evaluation (the learner's
    whole state at that evaluation, kept in memory). Each candidate must then beat the tree
    at z corrected for their number (`corrected_z`), the best scoring of those that do is
    kept, and the selection plays the evaluation episodes after the in-run ones, so that
    the episodes that picked a candidate do not also judge it."""

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


def corrected_z(z: float, candidates: int) -> float:
    """The z each of `candidates` tests needs so that the chance any one of them passes by
    luck stays that of one test at `z` (Bonferroni: a one-sided tail of 1 − Φ(z), split
    evenly)."""
    if candidates <= 1:
        return z
    tail = (1.0 - NormalDist().cdf(z)) / candidates
    return NormalDist().inv_cdf(1.0 - tail)


def choose(
    candidates: Mapping[str, Sequence[float]], tree_returns: Sequence[float], *, z: float
) -> Optional[str]:
    """The candidate to keep, by name: of those whose returns beat the tree's on the same
    episodes (`tree_wins` at `corrected_z`), the one with the highest mean; None: the tree.

    Raises:
        ValueError: there are no candidates, or one was not scored on the tree's episodes.
    """
    if not candidates:
        raise ValueError("the selection needs at least one candidate besides the tree")
    z_each = corrected_z(z, len(candidates))
    beat = {
        name: float(np.mean(returns))
        for name, returns in candidates.items()
        if not tree_wins(returns, tree_returns, z=z_each)
    }
    return max(beat, key=beat.__getitem__) if beat else None


def with_tree_only(weights: Weights, tree_only: bool) -> Weights:
    """`weights`, plus the ``TREE_ONLY`` entry when the greedy policy is μ alone (absent
    otherwise, so that a learner which never falls back publishes what it always did)."""
    import torch  # the config reads SelectionConfig from here before anything loads torch

    return {**weights, TREE_ONLY: torch.tensor(1.0)} if tree_only else weights
