"""The one place that wires a `DQNConfig` and gymnasium spaces into Double DQN objects."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Optional

import torch
from gymnasium import spaces

from actors.behaviours.epsilon_greedy import EpsilonGreedyBehaviour
from actors.hardcoded import ImportedPolicy, required_policy
from learner.agent import Budget, Phase, online_phase
from learner.device import CPU, CompileMode
from learner.dqn.config import DQNConfig
from learner.dqn.learning import DQNLearner
from learner.dqn.networks import make_q_network
from learner.spaces import discrete_actions, observation_dim
from learner.td3.networks import acting_copy


class DQNBuilder:
    """Double DQN as a run: one online phase, its warm-up ε = 1 (or demonstrations of the
    hard-coded policy, ε-greedy around μ(s), and a burn-in on them), then decaying ε-greedy."""

    def __init__(
        self,
        obs_space: spaces.Space,
        action_space: spaces.Space,
        *,
        config: DQNConfig,
        budget: Budget,
        seed: int,
        hardcoded_policy: Optional[str] = None,
        import_path: Sequence[str] = (),
    ) -> None:
        """`hardcoded_policy` (μ's import string, found on `import_path`) is used only with
        ``config.warmup`` = hardcoded.

        Raises ValueError when the observation space is not a flat Box, the actions are not
        Discrete, or warmup: hardcoded has no hard-coded policy that builds."""
        self.obs_dim = observation_dim(obs_space, "ddqn")
        self.num_actions = discrete_actions(action_space, "ddqn")
        self.config, self.budget, self.seed = config, budget, seed
        self.batch_size = config.batch_size
        self.hardcoded: Optional[ImportedPolicy] = None
        if config.warmup == "hardcoded":
            self.hardcoded = required_policy(
                hardcoded_policy,
                obs_space,
                action_space,
                method="ddqn with dqn.warmup=hardcoded",
                import_path=import_path,
            )

    def phases(self) -> list[Phase]:
        budget = self.budget
        phase = online_phase(
            budget,
            batch_size=self.batch_size,
            env_steps=budget.env_steps,
            warmup=True,
            burn_in_updates=self.config.burn_in_updates,
        )
        # n-step returns come from windows of n steps of one episode, drawn from replay.
        return [dataclasses.replace(phase, sequence_length=self.config.n_step)]

    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> DQNLearner:
        (phase,) = self.phases()
        return DQNLearner(
            self.obs_dim,
            self.num_actions,
            config=self.config,
            seed=self.seed,
            total_updates=phase.updates,
            device=device,
            compile=compile,
        )

    def make_behaviour(self, *, num_actors: int) -> EpsilonGreedyBehaviour:
        c = self.config
        return EpsilonGreedyBehaviour(
            acting_copy(make_q_network(self.obs_dim, self.num_actions, c.hidden_sizes)),
            epsilon_start=c.epsilon_start,
            epsilon_end=c.epsilon_end,
            decay_env_steps=c.epsilon_decay_env_steps,
            num_actors=num_actors,
            hardcoded=self.hardcoded,
            demo_epsilon=c.demo_epsilon,
            switch_margin=c.switch_margin,
        )
