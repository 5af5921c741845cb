"""Backbone networks: the correction actor π (zero output at start) and a loaded teacher."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from learner.td3.networks import Actor, TwinCritic, saved_layout, saved_standardized


def zero_output_(actor: Actor) -> Actor:
    """Zeroes the actor's last layer so π(s) = 0 everywhere: training starts as μ itself.

    The tanh squashing keeps 0 at 0 for the symmetric range [−L, L]; gradients still reach
    the last layer (through the hidden activations) and, after one step, the rest.
    """
    last = actor.net[-1]
    assert isinstance(last, torch.nn.Linear), f"the actor ends in {last}, not a linear layer"
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    return actor


def backbone_input(obs: torch.Tensor, backbone: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """The correction's input when it observes the backbone: [s, μ(s) / scale], [B, O + A]
    (`actors.behaviours.backbone.backbone_input` is the same for actors, in numpy)."""
    return torch.cat([obs, backbone / scale], dim=-1)


def load_teacher(
    path: str, obs_dim: int, act_dim: int, low: np.ndarray, high: np.ndarray
) -> tuple[Actor, TwinCritic]:
    """Loads μ̂ and Q̂ from a TD3 run folder (its latest checkpoint) or a checkpoint file.

    Raises:
        ValueError: If there is no checkpoint, or it is not a TD3 learner's.
    """
    from learner.checkpoint import find_checkpoint, load_checkpoint

    try:
        found, _ = find_checkpoint(Path(path))
    except FileNotFoundError as error:
        raise ValueError(f"teacher {path!r}: {error} (a TD3 run folder or .pt file)") from None
    state = load_checkpoint(found)["algorithm"]
    if "actor" not in state or "critic" not in state:
        raise ValueError(f"teacher {found}: not a TD3 checkpoint (no actor/critic)")
    widths, _ = saved_layout(state["actor"])
    standardized = saved_standardized(state["actor"], "net.")
    actor = Actor(obs_dim, act_dim, low, high, widths, standardized=standardized)
    actor.load_state_dict(state["actor"])
    q1 = {k: w for k, w in state["critic"].items() if k.startswith("q1_net.")}
    hidden, layer_norm = saved_layout(q1)
    critic = TwinCritic(obs_dim, act_dim, hidden, layer_norm=layer_norm, standardized=standardized)
    critic.load_state_dict(state["critic"])
    return actor.requires_grad_(False), critic.requires_grad_(False)
