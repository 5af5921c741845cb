"""The one place that wires backbone TD3 (sec. III-B, eq. 11) into run objects."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Optional

import numpy as np
import torch

from actors.behaviours.backbone import BackboneBehaviour
from actors.hardcoded import HardCodedPolicy, required_policy
from actors.policy_net import TwinQ
from learner.agent import Phase
from learner.backbone.config import PREFILLS, BackboneConfig
from learner.backbone.learning import ObservingBackboneLearner, TeacherBackboneLearner
from learner.backbone.networks import load_teacher, zero_output_
from learner.device import CPU, CompileMode
from learner.td3.builder import TD3Builder, make_actor_network
from learner.td3.learning import TD3Learner
from learner.td3.networks import TwinCritic, acting_copy
from service.core import as_arrays


class BackboneBuilder:
    """Backbone TD3: prefill with μ(s) + ε, then μ(s) + clip(π(s) + noise); with
    ``residual=False`` a standalone actor, centre + π(s) + noise, the tree a proposal."""

    def __init__(
        self,
        hardcoded_policy: Optional[str],
        td3: TD3Builder,
        *,
        config: BackboneConfig,
        import_path: Sequence[str] = (),
    ) -> None:
        """`hardcoded_policy` is μ's import string (unused with a teacher), `td3` holds the
        spaces and the TD3 side, `config` this method's own settings; `import_path` is
        where μ's package is found."""
        self.td3, self.config = td3, config
        self.batch_size = td3.batch_size
        self.centre: Optional[np.ndarray] = None
        """A standalone actor's base, the box's centre (None: the residual's, μ(s))."""
        if config.residual:
            self.bound = np.full(self.td3.act_dim, config.correction_limit, dtype=np.float32)
        else:  # π's range is the box around its centre, whatever correction_limit says
            self.bound = ((td3.high - td3.low) / 2).astype(np.float32)
            self.centre = ((td3.high + td3.low) / 2).astype(np.float32)
        self.teacher = (
            load_teacher(
                config.teacher, self.td3.obs_dim, self.td3.act_dim, self.td3.low, self.td3.high
            )
            if config.teacher
            else None
        )
        self.hardcoded = (
            None
            if self.teacher is not None
            else required_policy(
                hardcoded_policy,
                td3.obs_space,
                td3.action_space,
                method="backbone_td3",
                import_path=import_path,
            )
        )

    def phases(self) -> list[Phase]:
        return self.td3.phases()  # TD3's, its warm-up being the prefill a = μ(s) + ε

    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> TD3Learner:
        t = self.td3
        if self.teacher is not None:
            learner: TD3Learner = TeacherBackboneLearner(
                t.obs_dim,
                self.config.correction_limit,
                teacher=self.teacher,
                config=t.config,
                seed=t.seed,
                device=device,
                compile=compile,
            )
        elif self.config.observe_backbone:
            learner = ObservingBackboneLearner(
                t.obs_dim,
                self.bound,
                t.high,
                config=t.config,
                seed=t.seed,
                device=device,
                compile=compile,
                correction_penalty=self.config.correction_penalty,
                publish_critic=self._actors_need_critic(),
                ramp_actor_updates=self._ramp_actor_updates(),
                tree_in_target=self.config.tree_in_target,
                centre=self.centre,
                clone_tree=self.config.clone_tree,
                tree_input=self.config.tree_input,
            )
        else:
            learner = TD3Learner(
                t.obs_dim,
                t.act_dim,
                -self.bound,
                self.bound,
                config=t.config,
                seed=t.seed,
                device=device,
                compile=compile,
            )
        if self.config.residual:
            # The correction starts at zero output: at first the agent is the backbone.
            # A standalone actor keeps TD3's initialisation, as RL from scratch (and IBRL)
            # start theirs: a zero last layer would make π(s) one constant action, the
            # centre, and its gradient would reach the hidden layers only after a step.
            zero_output_(learner.actor)
            learner.target_actor.load_state_dict(learner.actor.state_dict())
        return learner

    def _limit(self) -> float:
        """The behaviour's clip on c: L (residual), or the box's largest half-width (the
        box itself then clips each dimension of centre + c)."""
        return self.config.correction_limit if self.centre is None else float(np.max(self.bound))

    def _actors_need_critic(self) -> bool:
        """Switching (greedy) and the tree's proposal in acting both choose by the critic."""
        return self.config.switch_margin is not None or self.config.tree_in_acting

    def _ramp_actor_updates(self) -> int:
        """The actor's gradient steps over which π's range widens (`correction_ramp`)."""
        c = self.td3.config
        updates = sum(p.updates for p in self.phases())
        actor_steps = max(updates - c.frozen_actor_updates, 0) // c.policy_delay
        return round(self.config.correction_ramp * actor_steps)

    def _backbone(self) -> HardCodedPolicy:
        if self.teacher is not None:
            return acting_copy(self.teacher[0])  # μ̂ for actors, in numpy
        assert self.hardcoded is not None
        return self.hardcoded

    def make_behaviour(self, *, num_actors: int) -> BackboneBehaviour:
        t = self.td3
        tree_input = self.config.observe_backbone and self.config.tree_input
        extra = t.act_dim if tree_input else 0
        correction = make_actor_network(
            t.obs_dim, t.act_dim, -self.bound, self.bound, t.config, extra_inputs=extra
        )
        critic = None
        if self._actors_need_critic():  # the behaviour's copy, in numpy as actors run it
            twin = TwinCritic(
                t.obs_dim + extra,
                t.act_dim,
                t.config.hidden_sizes,
                layer_norm=t.config.critic_layer_norm,
                standardized=t.config.standardized(t.obs_dim),
            )
            critic = TwinQ(as_arrays(twin.state_dict()))
        return BackboneBehaviour(
            acting_copy(correction),
            self._backbone(),
            limit=self._limit(),
            std=t.exploration_std,
            prefill_std=self.config.prefill_noise,
            prefill_uniform=PREFILLS[self.config.prefill],
            low=t.low,
            high=t.high,
            observe_backbone=self.config.observe_backbone,
            tree_input=tree_input,
            critic=critic,
            switch_margin=self.config.switch_margin,
            propose_tree=self.config.tree_in_acting,
            centre=self.centre,
        )
