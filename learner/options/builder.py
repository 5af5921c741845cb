"""The one place that wires the hierarchical options method (sec. III-C) into run objects."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Optional

import numpy as np
import torch

from actors.behaviours.options import OptionsBehaviour
from actors.hardcoded import required_policy
from learner.agent import Phase
from learner.backbone.networks import zero_output_
from learner.device import CPU, CompileMode
from learner.dqn.config import DQNConfig
from learner.dqn.learning import DQNLearner
from learner.options.config import OptionsConfig
from learner.options.learning import OptionsLearner, RetraceTD3Learner
from learner.options.networks import NUM_OPTIONS, make_option_network
from learner.td3.builder import TD3Builder, make_actor_network
from learner.td3.learning import TD3Learner
from learner.td3.networks import acting_copy


class OptionsBuilder:
    """One online phase whose table serves k-step windows; batches are `td3.batch_size` windows."""

    def __init__(
        self,
        hardcoded_policy: Optional[str],
        td3: TD3Builder,
        *,
        dqn: DQNConfig,
        config: OptionsConfig,
        import_path: Sequence[str] = (),
    ) -> None:
        """`hardcoded_policy` is the hard-coded option's import string, `td3` holds the
        spaces and the RL option, `dqn` the policy over options; `import_path` is where
        the hard-coded option's package is found."""
        self.td3, self.dqn, self.config = td3, dqn, config
        self.hardcoded = required_policy(
            hardcoded_policy,
            td3.obs_space,
            td3.action_space,
            method="options",
            import_path=import_path,
        )
        self.batch_size = td3.batch_size

    def phases(self) -> list[Phase]:
        k = self.config.option_length
        return [dataclasses.replace(p, sequence_length=k) for p in self.td3.phases()]

    def _rl_spaces(self) -> tuple[int, np.ndarray, np.ndarray]:
        """(input size, low, high) of the RL option's actor: [s, μ(s)] and [−L, L] when
        residual, else s and the action box."""
        t, limit = self.td3, self.config.residual_limit
        if limit is None:
            return t.obs_dim, t.low, t.high
        bound = np.full(t.act_dim, limit, dtype=np.float32)
        return t.obs_dim + t.act_dim, -bound, bound

    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> OptionsLearner:
        t = self.td3
        option_seed, rl_seed = np.random.SeedSequence(t.seed).generate_state(2)
        rl_in, low, high = self._rl_spaces()
        # Intra-option learning trains the RL option with TD3's own target, not eq. (14).
        kind: type[TD3Learner] = TD3Learner if self.config.intra_option else RetraceTD3Learner
        rl = kind(
            rl_in,
            t.act_dim,
            low,
            high,
            config=t.config,
            seed=int(rl_seed),
            device=device,
            compile=compile,
        )
        residual = self.config.residual_limit is not None
        if residual:  # the residual RL option starts as the hard-coded policy
            zero_output_(rl.actor)
            rl.target_actor.load_state_dict(rl.actor.state_dict())
        return OptionsLearner(
            DQNLearner(
                t.obs_dim,
                NUM_OPTIONS,
                config=self.dqn,
                seed=int(option_seed),
                device=device,
                compile=compile,
            ),
            rl,
            option_length=self.config.option_length,
            retrace_lambda=self.config.retrace_lambda,
            behaviour_std=t.exploration_std,
            gamma=self.dqn.gamma,
            residual_scale=torch.as_tensor(np.abs(t.high)) if residual else None,
            intra_option=self.config.intra_option,
        )

    def make_behaviour(self, *, num_actors: int) -> OptionsBehaviour:
        t, d = self.td3, self.dqn
        rl_in, low, high = self._rl_spaces()
        return OptionsBehaviour(
            acting_copy(make_option_network(t.obs_dim, d.hidden_sizes)),
            acting_copy(make_actor_network(rl_in, t.act_dim, low, high, t.config)),
            self.hardcoded,
            option_length=self.config.option_length,
            std=self.td3.exploration_std,
            low=t.low,
            high=t.high,
            epsilon_start=d.epsilon_start,
            epsilon_end=d.epsilon_end,
            decay_env_steps=d.epsilon_decay_env_steps,
            num_actors=num_actors,
            residual_limit=self.config.residual_limit,
            switch_margin=self.config.switch_margin,
        )
