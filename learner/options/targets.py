"""The targets of the hierarchical method: eq. (13) for options, eq. (14) Retrace for the RL option.

Window tensors are [B, k]: step t of a window sampled from replay, which never crosses an
episode end (it may end on one; one that ends early repeats its last step after it, and
`valid` marks the episode's steps). `discounts[:, t]` is γ(1 − terminated_t): truncation is not
termination, a time-limit cut still bootstraps.
"""

from __future__ import annotations

import math
from typing import Optional

import torch

_LOG_2PI = math.log(2.0 * math.pi)


def gaussian_log_prob(action: torch.Tensor, mean: torch.Tensor, std: float) -> torch.Tensor:
    """log N(a | mean, std² I), summed over the last (action) dimension."""
    z = (action - mean) / std
    return (-0.5 * z.pow(2) - math.log(std) - 0.5 * _LOG_2PI).sum(dim=-1)


def importance_ratio(
    action: torch.Tensor, target_mean: torch.Tensor, std: float, behaviour_log_prob: torch.Tensor
) -> torch.Tensor:
    """ρ = π(a|s) / π_old(a|s) on the UNCLIPPED sampled action a.

    π is a Gaussian of the actors' exploration std around the current actor's output; the
    behaviour density π_old(a|s) is the one the actor recorded when it sampled a.
    """
    return torch.exp(gaussian_log_prob(action, target_mean, std) - behaviour_log_prob)


def retrace_traces(ratio: torch.Tensor, lam: float) -> torch.Tensor:
    """Retrace traces c = λ · min(1, ρ) (Munos et al. 2016): truncation keeps variance bounded."""
    return lam * ratio.clamp(max=1.0)


def retrace_targets(
    rewards: torch.Tensor,
    discounts: torch.Tensor,
    next_values: torch.Tensor,
    next_q: torch.Tensor,
    next_traces: torch.Tensor,
) -> torch.Tensor:
    """Eq. (14) along a window, computed backwards from its last step.

    Q^ret_t = r_t + γ_t [V(s_{t+1}) + c_{t+1} (Q^ret_{t+1} − Q(s_{t+1}, a_{t+1}))],
    and at the window's last step (nothing sampled beyond it) Q^ret = r + γ V(s').

    Args:
        rewards: r_t, [B, k].
        discounts: γ(1 − terminated_t), [B, k].
        next_values: V(s_{t+1}) from the option-value network, [B, k].
        next_q: Q(s_{t+1}, a_{t+1}) from the TD3 target critic, [B, k] (last column unused).
        next_traces: c_{t+1}, [B, k] (last column unused); zero cuts the trace.

    Returns:
        Q^ret_t for every step of the window, [B, k], without gradient.
    """
    k = rewards.shape[1]
    out = torch.empty_like(rewards)
    out[:, k - 1] = rewards[:, k - 1] + discounts[:, k - 1] * next_values[:, k - 1]
    for t in range(k - 2, -1, -1):
        correction = next_traces[:, t] * (out[:, t + 1] - next_q[:, t])
        out[:, t] = rewards[:, t] + discounts[:, t] * (next_values[:, t] + correction)
    return out.detach()


def k_step_return(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    gamma: float,
    valid: Optional[torch.Tensor] = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The first half of eq. (13): (Σ_{i<m} γ^i r_i, γ^m (1 − d)) for windows [B, k], where m
    is the number of the window's steps that are its episode's (`valid`, a prefix; all k
    without it) and d whether the last of them is terminal.

    A window never crosses an episode end; one that reaches it early (an option cut short
    by its episode's end) repeats its last step after it, and those steps count for nothing.

    Returns:
        (returns [B], bootstrap discount [B]) for `double_q_target`.
    """
    k = rewards.shape[1]
    powers = gamma ** torch.arange(k, dtype=rewards.dtype, device=rewards.device)
    weights = powers if valid is None else powers * valid
    steps = k if valid is None else valid.to(rewards.dtype).sum(dim=1)
    alive = 1.0 - terminated[:, -1].to(rewards.dtype)
    return (rewards * weights).sum(dim=1), gamma**steps * alive
