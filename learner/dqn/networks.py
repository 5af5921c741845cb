"""The Q network Q(s, ·): an MLP with one output per discrete action (or option)."""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn

from learner.td3.networks import mlp


def make_q_network(obs_dim: int, num_actions: int, hidden_sizes: Sequence[int]) -> nn.Sequential:
    """Builds Q(s, ·): [B, obs_dim] -> [B, num_actions]."""
    return mlp(obs_dim, hidden_sizes, num_actions)
