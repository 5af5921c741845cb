"""The transition record every actor writes, as a replay-table signature.

The environment part (obs, reward, terminated, truncated, next_obs, policy_version,
acted_at) is common to all algorithms; the behaviour adds its own columns
(`Behaviour.columns`): at least `action`, the *unclipped* sampled behaviour action, and
`log_prob`, its log-likelihood under the behaviour policy: importance ratios are taken on
it. The environment (and the learner, before valuing it) clips it into bounds.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from gymnasium import spaces


def replay_signature(
    obs_space: spaces.Box, behaviour_columns: Mapping[str, Mapping[str, Any]]
) -> dict[str, Any]:
    """Column specs for one transition: ``{name: {"dtype", "shape"}}``."""
    obs = {"dtype": "float32", "shape": list(obs_space.shape)}
    return {
        "obs": obs,
        **behaviour_columns,
        "reward": {"dtype": "float32", "shape": []},
        # Truncation (time limit) is not termination: only `terminated` stops bootstrapping.
        "terminated": {"dtype": "bool", "shape": []},
        "truncated": {"dtype": "bool", "shape": []},
        "next_obs": obs,
        "policy_version": {"dtype": "int64", "shape": []},
        # Wall-clock seconds when the step was acted: the learner's `perf/policy_lag`.
        "acted_at": {"dtype": "float64", "shape": []},
    }


def transition_signature(obs_space: spaces.Box, action_space: spaces.Box) -> dict[str, Any]:
    """The signature of a Gaussian (TD3) behaviour over a Box action space."""
    return replay_signature(
        obs_space,
        {
            "action": {"dtype": "float32", "shape": list(action_space.shape)},
            "log_prob": {"dtype": "float32", "shape": []},
        },
    )
