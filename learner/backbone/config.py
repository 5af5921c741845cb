"""Hyper-parameters of backbone TD3 beyond TD3's own."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

PREFILLS = {"tree": 0.0, "mixed": 0.5, "uniform": 1.0}
"""What a backbone run's prefill may act (`BackboneConfig.prefill`) -> the share of its
steps that act uniformly in the box."""


@dataclass(frozen=True)
class BackboneConfig:
    """Backbone TD3 (sec. III-B); the TD3 part is `TD3Config`."""

    correction_limit: float = 1.0
    """L: the correction is clipped to [−L, L] (action units); narrow = stable, wide = room."""
    prefill_noise: float = 0.5
    """Std of ε in the prefill actions a = μ(s) + ε (action units)."""
    prefill: str = "tree"
    """What the prefill (the first ``learning_starts`` steps) acts: ``tree``, μ(s) + ε;
    ``uniform``, actions drawn uniformly from the box, as TD3 from scratch warms up (the
    tree then still proposes μ(s) in the TD target, in acting and in the greedy policy);
    ``mixed``, each step either, at even odds: uniform actions in the states the tree
    leads to."""
    teacher: Optional[str] = None
    """A trained TD3 run folder (or checkpoint) as backbone μ̂ with critic Q̂: eq. (11)."""
    observe_backbone: bool = False
    """Give μ(s) (scaled to [−1, 1]) to the correction actor and the critics as an extra
    input, as residual policy learning does. The paper's π(s) sees s only; with a bang-bang
    μ the correction it needs is discontinuous in s (μ flips with sign θ̇) but not in μ(s)."""
    tree_input: bool = True
    """With observe_backbone: π and the critics see μ(s) beside s. False: they see s alone,
    as IBRL's networks do (a standalone actor's best action is a function of s; a bang-bang
    μ(s) beside it is an input that flips where the action should be smooth, at Pendulum's
    top as θ̇ changes sign), and μ(s) travels in the batches only as the tree's proposal
    (tree_in_acting, tree_in_target, switching). Measured on Pendulum's 10 seeds: no gain
    (+0.7 [−3.1, +4.1] against true), so the recipe keeps true (docs/own-task.md)."""

    correction_penalty: float = 0.0
    """β, conservative updates near the backbone: the actor minimises
    −Q(s, π(s)) / mean|Q| + β · mean((π(s) / L)²), so a correction grows only where the
    critic's gain outweighs it (TD3+BC's normalisation, Fujimoto & Gu 2021, with the
    backbone as the behaviour). 0: TD3's actor loss. Needs observe_backbone."""

    switch_margin: Optional[float] = None
    """Value-based switching: the greedy policy acts μ(s) + π(s) only where
    min(Q1, Q2)(s, π(s)) > min(Q1, Q2)(s, 0) + margin · |min(Q1, Q2)(s, 0)|, else the tree
    μ(s) alone (`actors.behaviours.switching`). None: no switching. Needs observe_backbone
    (the critic values a correction next to μ(s))."""

    correction_ramp: float = 0.0
    """A trust region that widens: π's range grows linearly from 0 to [−L, L] over this
    share of the actor's gradient steps in the run (0: the whole range from the first
    step). Early in a run the critic knows little beyond the tree's actions, and a
    correction it trusts can take the agent far from them; a narrow range keeps the
    policy near the tree until the critic has seen where π's corrections lead. Needs
    observe_backbone."""

    tree_in_target: bool = False
    """The tree as a proposal in the TD target (IBRL, Hu et al. 2023, eq. 3): y = r +
    γ max(Q'(s', π'(s')), Q'(s', μ(s'))), each the smaller twin estimate, so that the
    critic values the better of the two continuations and π is pulled up to the tree
    wherever the tree is worth more. Needs observe_backbone."""
    tree_in_acting: bool = False
    """The tree as a proposal in acting (IBRL): each training step acts around π's action
    or the tree's, whichever min(Q1, Q2) values higher, the exploration noise added to the
    one chosen. Needs observe_backbone (the actors get the critic with the weights)."""
    residual: bool = True
    """True: π is a correction, a = μ(s) + clip(π(s), [−L, L]), starting at zero output
    (the agent starts as the tree). False: a standalone actor, as in IBRL (Hu et al. 2023):
    a = clip(centre + π(s)), π's range the action box around its centre (correction_limit
    is not used), TD3's own initialisation; the tree only proposes μ(s) (as the
    "correction" μ(s) − centre) in the prefill, and where tree_in_acting, tree_in_target
    and switch_margin choose by Q. Needs observe_backbone; refuses correction_penalty
    and correction_ramp (both measure π from the tree's 0)."""
    clone_tree: bool = False
    """A standalone actor that starts as a copy of the tree: while the actor is frozen
    (``td3.frozen_actor_updates``, the critic's burn-in) each delayed actor step fits
    π(s) to μ(s) − centre by the paper's imitation loss, eq. (8) (behaviour cloning, as in
    its pre-training, sec. III-A) instead of leaving π at its initialisation; the
    critic's TD target follows the cloned π' meanwhile. Needs residual=False (a residual
    starts as the tree already). Measured on one seed: TD3's first steps undo the copy,
    and the finals moved no more than between two runs (docs/own-task.md), so the recipe
    leaves it off."""

    def __post_init__(self) -> None:
        if not self.correction_limit > 0.0:
            raise ValueError(
                f"correction_limit={self.correction_limit} must be > 0: the correction range "
                "[-L, L] would be empty and the policy could never improve on the backbone"
            )
        if not self.prefill_noise > 0.0:
            raise ValueError(f"prefill_noise={self.prefill_noise} must be > 0 (log_prob needs it)")
        if self.prefill not in PREFILLS:
            raise ValueError(f"prefill={self.prefill!r} must be one of {', '.join(PREFILLS)}")
        if not self.correction_penalty >= 0.0:
            raise ValueError(f"correction_penalty={self.correction_penalty} must be >= 0")
        if self.switch_margin is not None and not self.switch_margin >= 0.0:
            raise ValueError(
                f"switch_margin={self.switch_margin} must be >= 0 (a fraction of "
                "|Q(s, μ(s))| the correction must gain), or null for no switching"
            )
        if not 0.0 <= self.correction_ramp <= 1.0:
            raise ValueError(
                f"correction_ramp={self.correction_ramp} must be in [0, 1] (a share of the "
                "actor's gradient steps; 0: no ramp)"
            )
        observing = {  # the parts that work on the observing learner's inputs and critic
            "correction_penalty": self.correction_penalty > 0.0,
            "switch_margin": self.switch_margin is not None,
            "correction_ramp": self.correction_ramp > 0.0,
            "tree_in_target": self.tree_in_target,
            "tree_in_acting": self.tree_in_acting,
        }
        for name in [n for n, used in observing.items() if used and not self.observe_backbone]:
            raise ValueError(
                f"{name}={getattr(self, name)} needs observe_backbone=True (the residual "
                "learner); set backbone.observe_backbone: true"
            )
        if not self.tree_input and (self.residual or not self.observe_backbone):
            raise ValueError(
                "tree_input=False needs a standalone actor (residual=False, which needs "
                "observe_backbone=True): a residual correction is defined next to μ(s); set "
                "backbone.residual: false or backbone.tree_input: true"
            )
        if not self.residual:
            self._check_standalone()
        elif self.clone_tree:
            raise ValueError(
                "clone_tree=True needs residual=False: a residual correction starts at 0, "
                "as the tree already; set backbone.residual: false"
            )
        if self.observe_backbone and self.teacher:
            raise ValueError(
                "observe_backbone=True with a teacher is not supported: the teacher's critic "
                "Q̂ takes s only; drop one of backbone.observe_backbone / backbone.teacher"
            )

    def _check_standalone(self) -> None:
        """The settings a standalone actor (residual=False) cannot take, by name."""
        if not self.observe_backbone:
            raise ValueError(
                "residual=False needs observe_backbone=True (the tree's proposal μ(s) travels "
                "in the observing learner's batches); set backbone.observe_backbone: true"
            )
        for name in ("correction_penalty", "correction_ramp"):
            if getattr(self, name) > 0.0:
                raise ValueError(
                    f"{name}={getattr(self, name)} needs residual=True: it keeps π near the "
                    "correction 0, which a standalone actor's output is not (the box's centre)"
                )
