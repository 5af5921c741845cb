"""Algorithm name (a preset's `algorithm:`) -> its builder, wired from the parsed config."""

from __future__ import annotations

from typing import TYPE_CHECKING

from learner.agent import AgentBuilder, Budget

if TYPE_CHECKING:
    from graft.config import TrainConfig


def make_builder(config: TrainConfig) -> AgentBuilder:
    """Returns the builder of `config.algorithm` for the config's task.

    Raises:
        ValueError: unknown algorithm, or spaces / settings the algorithm refuses.
    """
    env = config.make_env()
    obs_space, action_space = env.observation_space, env.action_space
    env.close()
    budget = Budget(
        env_steps=config.online_env_steps,
        learning_starts=config.learning_starts,
        updates_per_env_step=config.updates_per_env_step,
        slack_env_steps=config.slack_env_steps,
    )
    if config.algorithm == "ddqn":
        from learner.dqn.builder import DQNBuilder

        return DQNBuilder(
            obs_space,
            action_space,
            config=config.dqn,
            budget=budget,
            seed=config.seed,
            hardcoded_policy=config.hardcoded_policy,
            import_path=config.import_path,
        )
    # Every other algorithm is TD3 plus something: the TD3 builder checks the spaces.
    from learner.td3.builder import TD3Builder

    td3 = TD3Builder(
        obs_space,
        action_space,
        config=config.td3,
        method=config.algorithm,
        budget=budget,
        seed=config.seed,
    )
    # The methods that improve a hard-coded policy get its import string, and build it.
    policy, path = config.hardcoded_policy, config.import_path
    if config.algorithm == "td3":
        return td3
    if config.algorithm == "backbone_td3":
        from learner.backbone.builder import BackboneBuilder

        return BackboneBuilder(policy, td3, config=config.backbone, import_path=path)
    if config.algorithm == "pretrain_td3":
        from learner.pretrain.builder import PretrainBuilder

        return PretrainBuilder(policy, td3, config=config.pretrain, import_path=path)
    if config.algorithm == "options":
        from learner.options.builder import OptionsBuilder

        return OptionsBuilder(policy, td3, dqn=config.dqn, config=config.options, import_path=path)
    raise ValueError(f"unknown algorithm {config.algorithm!r}")
