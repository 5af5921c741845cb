"""The one place that wires a `TD3Config` and gymnasium spaces into TD3 objects."""

from __future__ import annotations

import dataclasses

import numpy as np
import torch
from gymnasium import spaces

from actors.behaviours.gaussian import GaussianBehaviour
from learner.agent import Budget, Phase, online_phase
from learner.device import CPU, CompileMode
from learner.spaces import box_action_dim, observation_dim
from learner.td3.config import TD3Config, layer_norm_setting
from learner.td3.learning import TD3Learner
from learner.td3.networks import Actor, acting_copy


def make_actor_network(
    obs_dim: int,
    act_dim: int,
    low: np.ndarray,
    high: np.ndarray,
    config: TD3Config,
    *,
    extra_inputs: int = 0,
) -> Actor:
    """Builds the TD3 actor architecture, e.g. for an actor loading broadcast weights.

    Args:
        obs_dim: Observation size.
        act_dim: Action size.
        low: Lower action bounds, shape [act_dim].
        high: Upper action bounds, shape [act_dim].
        config: Supplies `hidden_sizes` and `standardize_observations`.
        extra_inputs: Inputs after the observation's (the backbone's μ(s)), as the
            learner's `TD3Learner` takes them.

    Returns:
        A freshly initialised `Actor` whose `state_dict` matches `TD3Learner.policy_state()`.
    """
    standardized = config.standardized(obs_dim)
    return Actor(
        obs_dim + extra_inputs, act_dim, low, high, config.hidden_sizes, standardized=standardized
    )


def critic_layer_norm_for(setting: str | bool, obs_space: spaces.Space) -> str:
    """`TD3Config.critic_layer_norm` for these observations: ``auto`` is ``all`` where the
    space leaves a bound open (±inf: raw scales the task does not state, as MuJoCo's
    velocities) and ``none`` where every bound is finite; any other setting is itself."""
    setting = layer_norm_setting(setting)
    if setting != "auto":
        return setting
    assert isinstance(obs_space, spaces.Box)
    bounded = np.isfinite(obs_space.low).all() and np.isfinite(obs_space.high).all()
    return "none" if bounded else "all"


def for_observations(config: TD3Config, obs_space: spaces.Space) -> TD3Config:
    """`config` with its ``auto`` settings resolved against the observation space."""
    layer_norm = critic_layer_norm_for(config.critic_layer_norm, obs_space)
    return dataclasses.replace(config, critic_layer_norm=layer_norm)


def make_td3_learner(
    obs_space: spaces.Space,
    action_space: spaces.Space,
    config: TD3Config,
    seed: int,
    *,
    device: torch.device = CPU,
    compile: CompileMode = "off",
) -> TD3Learner:
    """Builds a `TD3Learner` for the given spaces, on `device`.

    Args:
        obs_space: 1-D Box observation space.
        action_space: 1-D Box action space with finite bounds.
        config: TD3 hyper-parameters.
        seed: Seeds network initialisation and target smoothing noise.
        device: Where the learner computes.
        compile: Whether its networks are compiled (`learner.device.compile_networks`).

    Returns:
        The learner.

    Raises:
        ValueError: If a space is not a 1-D Box, or the action bounds are not finite.
    """
    obs_dim = observation_dim(obs_space, "td3")
    act_dim = box_action_dim(action_space, "td3")
    assert isinstance(action_space, spaces.Box)
    return TD3Learner(
        obs_dim,
        act_dim,
        np.asarray(action_space.low, dtype=np.float32),
        np.asarray(action_space.high, dtype=np.float32),
        config=for_observations(config, obs_space),
        seed=seed,
        device=device,
        compile=compile,
    )


class TD3Builder:
    """TD3 as a run: one online phase, uniform warm-up, Gaussian exploration."""

    def __init__(
        self,
        obs_space: spaces.Space,
        action_space: spaces.Space,
        *,
        config: TD3Config,
        budget: Budget,
        seed: int,
        method: str = "td3",
    ) -> None:
        """`method` is the algorithm built on these TD3 parts, named when a space is refused.

        Raises:
            ValueError: The observation space is not a flat Box, or the action space not a
                bounded 1-D Box.
        """
        self.obs_dim = observation_dim(obs_space, method)
        self.act_dim = box_action_dim(action_space, method)
        self.obs_space, self.action_space = obs_space, action_space
        assert isinstance(action_space, spaces.Box)
        self.low = np.asarray(action_space.low, dtype=np.float32)
        self.high = np.asarray(action_space.high, dtype=np.float32)
        self.config, self.budget, self.seed = for_observations(config, obs_space), budget, seed
        self.batch_size = config.batch_size

    def phases(self) -> list[Phase]:
        return [
            online_phase(
                self.budget,
                batch_size=self.batch_size,
                env_steps=self.budget.env_steps,
                warmup=True,
                burn_in_updates=self.config.burn_in_updates,
            )
        ]

    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> TD3Learner:
        return make_td3_learner(
            self.obs_space,
            self.action_space,
            self.config,
            self.seed,
            device=device,
            compile=compile,
        )

    def make_behaviour(self, *, num_actors: int) -> GaussianBehaviour:
        network = make_actor_network(self.obs_dim, self.act_dim, self.low, self.high, self.config)
        return GaussianBehaviour(
            acting_copy(network), std=self.exploration_std, low=self.low, high=self.high
        )

    @property
    def exploration_std(self) -> float:
        """Absolute std of the behaviour noise: `exploration_noise` times the max action."""
        return self.config.exploration_noise * float(np.max(np.abs(self.high)))
