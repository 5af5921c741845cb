"""TD3 networks: a deterministic tanh actor and a twin Q critic, plain MLPs."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch
from torch import nn

from actors.policy_net import PolicyNet
from learner.td3.config import layer_norm_setting
from service.core import as_arrays


class Standardize(nn.Module):
    """The first `features` inputs centred and scaled, ``(x - shift) / scale``, the rest
    as they are: the identity until `fit_standardizers` sets both from data; buffers, so
    they travel with the weights (published, checkpointed) and Polyak averaging leaves
    them alone."""

    shift: torch.Tensor
    scale: torch.Tensor

    def __init__(self, features: int) -> None:
        super().__init__()
        self.register_buffer("shift", torch.zeros(features))
        self.register_buffer("scale", torch.ones(features))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n = self.shift.shape[0]
        return torch.cat([(x[..., :n] - self.shift) / self.scale, x[..., n:]], dim=-1)


@torch.no_grad()
def fit_standardizers(networks: Sequence[nn.Module], obs: torch.Tensor) -> None:
    """Sets every `Standardize` in `networks` from observations [B, O]: the shift is each
    feature's mean, the scale its standard deviation where that exceeds 1 and 1 elsewhere
    (large raw scales shrink to one; nothing is amplified, so a feature that barely moved
    in these data cannot blow up later)."""
    shift = obs.mean(dim=0)
    scale = obs.std(dim=0, correction=0).clamp_min(1.0)
    for module in (m for network in networks for m in network.modules()):
        if isinstance(module, Standardize):
            n = module.shift.shape[0]
            module.shift.copy_(shift[:n])
            module.scale.copy_(scale[:n])


def mlp(
    in_dim: int,
    hidden_sizes: Sequence[int],
    out_dim: int,
    *,
    layer_norm: str | bool = "none",
    standardized: int = 0,
) -> nn.Sequential:
    """Builds ``[Standardize ->] Linear -> [LayerNorm ->] ReLU -> ... -> Linear`` with the
    given hidden widths.

    Args:
        in_dim: Input features.
        hidden_sizes: Widths of the hidden layers, each followed by a ReLU.
        out_dim: Output features (no activation on the last layer).
        layer_norm: Where a LayerNorm goes between a hidden Linear and its ReLU: ``none``,
            ``first`` (the first hidden layer: features of raw, unscaled observations on
            one scale) or ``all`` (RLPD's critics, Ball et al., 2023: it bounds Q's growth
            off the data); a bool reads as ``all``/``none`` (`layer_norm_setting`).
        standardized: How many leading inputs (the observation's) a `Standardize` takes
            first; 0: none.

    Returns:
        The MLP.
    """
    setting = layer_norm_setting(layer_norm)
    if setting == "auto":
        raise ValueError("layer_norm='auto' is resolved against the observation space first")
    normed = {"none": 0, "first": 1, "all": len(hidden_sizes)}[setting]
    layers: list[nn.Module] = [Standardize(standardized)] if standardized else []
    for i, width in enumerate(hidden_sizes):
        layers += [nn.Linear(in_dim, width), *([nn.LayerNorm(width)] if i < normed else [])]
        layers.append(nn.ReLU())
        in_dim = width
    layers.append(nn.Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


def saved_layout(state: Mapping[str, torch.Tensor]) -> tuple[tuple[int, ...], str]:
    """A saved `mlp`'s hidden widths and where its LayerNorms are (``none``, ``first`` or
    ``all``), read from its weights alone: a Linear's weight is 2-d ([out, in]), a
    LayerNorm's 1-d (a `Standardize`'s shift and scale are neither)."""
    weights = [w for k, w in state.items() if k.endswith(".weight")]
    widths = tuple(int(w.shape[0]) for w in weights if w.dim() == 2)[:-1]
    normed = sum(w.dim() == 1 for w in weights)
    if normed == 0:
        return widths, "none"
    return widths, "first" if normed == 1 < len(widths) else "all"


def acting_copy(network: nn.Module) -> PolicyNet:
    """The network as actors run it: its weights in a numpy `PolicyNet` (no torch there)."""
    return PolicyNet(as_arrays(network.state_dict()))


class Actor(nn.Module):
    """Deterministic policy pi(s): an MLP whose tanh output is rescaled into [low, high]."""

    action_low: torch.Tensor
    action_high: torch.Tensor

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        hidden_sizes: Sequence[int],
        *,
        standardized: int = 0,
    ) -> None:
        """Creates the actor.

        Args:
            obs_dim: Observation size.
            act_dim: Action size.
            action_low: Lower action bounds, shape [act_dim], finite.
            action_high: Upper action bounds, shape [act_dim], finite and > low.
            hidden_sizes: Widths of the hidden ReLU layers.
            standardized: Leading inputs a `Standardize` takes first (`mlp`).

        Raises:
            ValueError: If the bounds have the wrong shape, are not finite or are empty.
        """
        super().__init__()
        # Copies: a buffer sharing the caller's array would change with it, and back.
        low = torch.tensor(np.asarray(action_low, dtype=np.float32))
        high = torch.tensor(np.asarray(action_high, dtype=np.float32))
        if low.shape != (act_dim,) or high.shape != (act_dim,):
            raise ValueError(
                f"action bounds have shapes {tuple(low.shape)} and {tuple(high.shape)}, "
                f"expected ({act_dim},) each."
            )
        if not (torch.isfinite(low).all() and torch.isfinite(high).all() and (low < high).all()):
            raise ValueError(
                f"action bounds must be finite with low < high, got low={low.tolist()}, "
                f"high={high.tolist()}; a tanh actor cannot cover an unbounded box."
            )
        self.net = mlp(obs_dim, hidden_sizes, act_dim, standardized=standardized)
        self.register_buffer("action_low", low)
        self.register_buffer("action_high", high)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Returns pi(obs) in [low, high], shape [B, act_dim]."""
        centre = (self.action_high + self.action_low) / 2
        half_width = (self.action_high - self.action_low) / 2
        return centre + half_width * torch.tanh(self.net(obs))


class TwinCritic(nn.Module):
    """Two independent Q networks Q1(s, a), Q2(s, a) (clipped double Q learning)."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int],
        *,
        layer_norm: str | bool = "none",
        standardized: int = 0,
    ) -> None:
        """Creates both critics.

        Args:
            obs_dim: Observation size.
            act_dim: Action size.
            hidden_sizes: Widths of the hidden ReLU layers of each critic.
            layer_norm: Where each critic gets a LayerNorm (`mlp`).
            standardized: Leading observation inputs each critic standardizes first.
        """
        super().__init__()
        self.q1_net, self.q2_net = (
            mlp(
                obs_dim + act_dim, hidden_sizes, 1, layer_norm=layer_norm, standardized=standardized
            )
            for _ in range(2)
        )

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns (Q1(s, a), Q2(s, a)), each of shape [B]."""
        x = torch.cat([obs, act], dim=-1)
        return self.q1_net(x).squeeze(-1), self.q2_net(x).squeeze(-1)

    def q1(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """Returns Q1(s, a), shape [B]; the actor is trained against this head only."""
        return self.q1_net(torch.cat([obs, act], dim=-1)).squeeze(-1)


def saved_standardized(state: Mapping[str, torch.Tensor], prefix: str = "") -> int:
    """How many inputs a saved `mlp` (its keys under `prefix`) standardizes: its
    `Standardize`'s width, 0 without one."""
    shift = state.get(f"{prefix}0.shift")
    return 0 if shift is None else int(shift.shape[0])
