"""Value-based switching between the hard-coded policy μ and the learned policy π.

At each step the greedy policy acts π's action only where the critic values it above μ's
by a margin, else μ's: the tree is kept unless π is confidently better there. The
estimate is conservative: the smaller of twin critics for continuous actions, and a
margin relative to the value of μ's action, so that the rule means the same on every
reward scale. A run whose final selection found π no better than μ publishes
``TREE_ONLY`` (`learner.selection.with_tree_only`): its greedy policy is then μ itself.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from service.core import WeightArrays

TREE_ONLY = "tree_only"
"""Published-weights key (a scalar, 1: the greedy policy acts μ alone;
`learner.selection.with_tree_only` adds it)."""
CRITIC_PREFIX = "critic."
"""Published-weights prefix of the critic's parameters, when the behaviour switches."""


def switch_mask(q_tree: np.ndarray, q_policy: np.ndarray, margin: float) -> np.ndarray:
    """Where π's action is taken: Q(s, π) > Q(s, μ) + margin · |Q(s, μ)|.

    Args:
        q_tree: Q(s, μ(s)), [B] (continuous: the smaller of the twin critics').
        q_policy: Q(s, π(s)), [B], the same critic(s).
        margin: ≥ 0, a fraction of |Q(s, μ(s))| π must gain (0: any gain; ties keep μ).

    Returns:
        [B] bool, True where π acts.
    """
    q_tree, q_policy = np.asarray(q_tree), np.asarray(q_policy)
    return q_policy > q_tree + margin * np.abs(q_tree)


def check_margin(name: str, margin: Optional[float]) -> None:
    """Refuses a switching margin that is neither None (no switching) nor ≥ 0."""
    if margin is not None and not margin >= 0.0:
        raise ValueError(
            f"{name}={margin} must be >= 0 (a fraction of |Q(s, μ(s))| π must gain over the "
            "tree to act), or null for no switching"
        )


def split_weights(weights: WeightArrays) -> tuple[WeightArrays, WeightArrays, bool]:
    """Published weights -> (the policy network's, the critic's (prefix dropped), tree only)."""
    tree_only = bool(np.asarray(weights[TREE_ONLY]).item()) if TREE_ONLY in weights else False
    critic = {k[len(CRITIC_PREFIX) :]: v for k, v in weights.items() if k.startswith(CRITIC_PREFIX)}
    policy = {
        k: v for k, v in weights.items() if k != TREE_ONLY and not k.startswith(CRITIC_PREFIX)
    }
    return policy, critic, tree_only
