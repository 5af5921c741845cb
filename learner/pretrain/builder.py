"""The one place that wires pre-training from a hard-coded policy into run objects."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Optional

import torch

from actors.behaviours.gaussian import GaussianBehaviour
from actors.hardcoded import required_policy
from learner.agent import Phase, online_phase
from learner.device import CPU, CompileMode
from learner.pretrain.config import PretrainConfig
from learner.pretrain.learning import PretrainLearner, pretrain_step
from learner.td3.builder import TD3Builder, make_actor_network
from learner.td3.networks import acting_copy


class PretrainBuilder:
    """Two phases: N demonstrations μ(s) + N(0, σ²) and pre-training on them, then online
    TD3 from the pre-trained networks (none if the budget is only the demonstrations)."""

    def __init__(
        self,
        hardcoded_policy: Optional[str],
        td3: TD3Builder,
        *,
        config: PretrainConfig,
        import_path: Sequence[str] = (),
    ) -> None:
        """`hardcoded_policy` is the demonstrator μ's import string, `td3` holds the spaces
        and the TD3 side, `config` this method's own settings; `import_path` is where μ's
        package is found."""
        self.td3, self.config = td3, config
        self.hardcoded = required_policy(
            hardcoded_policy,
            td3.obs_space,
            td3.action_space,
            method="pretrain_td3",
            import_path=import_path,
        )
        self.batch_size = td3.batch_size

    def phases(self) -> list[Phase]:
        c, budget = self.config, self.td3.budget
        demos = Phase(
            name="demos",
            env_steps=c.demo_steps,
            updates=c.pretrain_updates,
            min_size=c.demo_steps,  # pre-training starts on the full data set
            warmup_steps=c.demo_steps,
            step=pretrain_step,
            acts_with_weights=False,
        )
        if budget.env_steps == 0:
            return [demos]
        online = online_phase(
            budget,
            batch_size=self.batch_size,
            env_steps=budget.env_steps,
            warmup=False,
            burn_in_updates=self.td3.config.burn_in_updates,
        )
        return [demos, online]

    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> PretrainLearner:
        t, c = self.td3, self.config
        return PretrainLearner(
            t.obs_dim,
            t.act_dim,
            t.low,
            t.high,
            config=t.config,
            seed=t.seed,
            pretrain_loss=c.pretrain_loss,
            online_loss=c.online_loss,
            bc_alpha=c.bc_alpha,
            device=device,
            compile=compile,
        )

    def make_behaviour(self, *, num_actors: int) -> GaussianBehaviour:
        t = self.td3
        return GaussianBehaviour(
            acting_copy(make_actor_network(t.obs_dim, t.act_dim, t.low, t.high, t.config)),
            std=t.exploration_std,
            low=self.td3.low,
            high=self.td3.high,
            hardcoded=self.hardcoded,
            warmup_std=self.config.demo_noise,
        )
