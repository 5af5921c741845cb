"""The paper's figures as data: each a title and its variants (a preset plus overrides).

`runner` runs a figure's variants over seeds; `plots` draws it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

HARD_CODED_LEVEL = -429.0
"""The hard-coded Pendulum policy, `graft eval --policy hardcoded` (100 episodes)."""


@dataclass(frozen=True)
class Variant:
    """One line of a figure: a preset and the overrides that make it this variant."""

    label: str
    preset: str
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Figure:
    """A figure: its variants, what is plotted and the budget every variant shares."""

    name: str
    title: str
    variants: tuple[Variant, ...]
    final_only: bool = False
    """Plot the last evaluation per variant (fig. 2) instead of curves over env steps."""
    shared: dict[str, Any] = field(default_factory=dict)
    """Overrides applied to every variant (before its own)."""


_DEMO_NOISES = (0.1, 0.5, 1.0, 2.0)
_PAPER_BACKBONE = {
    "learning_starts": 1000,
    "td3.burn_in_updates": 0,
    "td3.frozen_actor_updates": 0,
    "backbone.correction_limit": 2.0,
    "backbone.prefill_noise": 0.5,
    "backbone.observe_backbone": False,
    "td3.exploration_noise": 0.1,
}
FIGURES = {
    "fig2": Figure(
        "fig2",
        "Fig. 2: TD3 fully offline on 10k hard-coded transitions, 20k updates",
        tuple(
            Variant(f"offline TD3, σ={s}", "pendulum-offline-td3", {"pretrain.demo_noise": s})
            for s in _DEMO_NOISES
        )
        + tuple(
            Variant(
                f"offline TD3+BC, σ={s}",
                "pendulum-offline-td3",
                {"pretrain.demo_noise": s, "pretrain.pretrain_loss": "td3_bc"},
            )
            for s in _DEMO_NOISES
        ),
        final_only=True,
    ),
    "fig3": Figure(
        "fig3",
        "Fig. 3: TD3 from scratch vs pre-trained (eqs. 8-9), frozen actor, TD3+BC, burn-in",
        (
            Variant("TD3 from scratch", "pendulum-td3"),
            Variant("pre-trained", "pendulum-pretrained-td3"),
            Variant(
                "pre-trained, actor frozen 5k",
                "pendulum-pretrained-td3",
                {"td3.frozen_actor_updates": 5000},
            ),
            Variant("TD3+BC", "pendulum-td3bc"),
            Variant("critic burn-in", "pendulum-burnin"),
        ),
    ),
    "fig4": Figure(
        "fig4",
        "Fig. 4: TD3 vs TD3 with the hard-coded policy as backbone (clip range L)",
        (
            Variant("TD3", "pendulum-td3"),
            # Control for the backbone's burn-in: TD3 with the same extra updates at 2k steps.
            Variant(
                "TD3 + burn-in",
                "pendulum-td3",
                {"learning_starts": 2000, "td3.burn_in_updates": 4000},
            ),
            # The preset's recipe (μ(s) observed, wide prefill, critic burn-in) over clip
            # ranges L. With a bang-bang backbone (μ = ±2) only L >= 4 lets a = clip(μ + c)
            # reach every torque in [-2, 2]; narrower ranges keep the action on μ's side.
            *(
                Variant(
                    f"backbone L={limit}", "pendulum-backbone", {"backbone.correction_limit": limit}
                )
                for limit in (4.0, 2.0, 1.0)
            ),
            # The paper's own setting: π(s) sees s only, 1,000 prefill steps of σ = 0.5,
            # no burn-in.
            Variant("backbone (paper) L=2.0", "pendulum-backbone", _PAPER_BACKBONE),
        ),
    ),
    "fig5": Figure(
        "fig5",
        "Figs. 5-6: hierarchical options {hard-coded, RL}, k = 10, Retrace",
        (Variant("options", "pendulum-options"),),
    ),
}
