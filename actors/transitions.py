"""The transition record every actor writes, as a replay-table signature.

`action` is the *unclipped* sampled behaviour action and `log_prob` its
log-likelihood under the behaviour policy: importance ratios are taken on it.
The environment (and the learner, before valuing it) clips it into bounds.
"""

from __future__ import annotations

from typing import Any

from gymnasium import spaces


def transition_signature(obs_space: spaces.Box, action_space: spaces.Box) -> dict[str, Any]:
    """Column specs for one transition: ``{name: {"dtype", "shape"}}``."""
    obs = {"dtype": "float32", "shape": list(obs_space.shape)}
    return {
        "obs": obs,
        "action": {"dtype": "float32", "shape": list(action_space.shape)},
        "reward": {"dtype": "float32", "shape": []},
        # Truncation (time limit) is not termination: only `terminated` stops bootstrapping.
        "terminated": {"dtype": "bool", "shape": []},
        "truncated": {"dtype": "bool", "shape": []},
        "next_obs": obs,
        "log_prob": {"dtype": "float32", "shape": []},
        "policy_version": {"dtype": "int64", "shape": []},
    }
