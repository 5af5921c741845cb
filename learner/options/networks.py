"""Networks of the hierarchical method: the option-value network Q_Ω(s, o) over two options.

The RL option's actor and twin critic are TD3's (learner/td3/networks.py).
"""

from __future__ import annotations

from collections.abc import Sequence

from torch import nn

from learner.dqn.networks import make_q_network

NUM_OPTIONS = 2
"""Option 0 is the hard-coded policy, option 1 the RL policy."""


def make_option_network(obs_dim: int, hidden_sizes: Sequence[int]) -> nn.Sequential:
    """Q_Ω: [B, obs_dim] -> [B, 2], the value of starting each option in s (eq. 13)."""
    return make_q_network(obs_dim, NUM_OPTIONS, hidden_sizes)
