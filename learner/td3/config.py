"""Hyper-parameters of TD3 (Fujimoto et al., 2018), as one frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass

LAYER_NORMS = ("none", "first", "all", "auto")


def layer_norm_setting(value: str | bool) -> str:
    """`critic_layer_norm` as one of `LAYER_NORMS`: a bool (how runs before ``first``
    recorded it) reads as ``all`` or ``none``."""
    if isinstance(value, bool):
        return "all" if value else "none"
    if value not in LAYER_NORMS:
        raise ValueError(
            f"critic_layer_norm={value!r} must be one of {', '.join(LAYER_NORMS)} (or true/false)."
        )
    return value


@dataclass(frozen=True)
class TD3Config:
    """TD3 hyper-parameters; defaults follow Fujimoto et al. (2018).

    Noise scales are fractions of the largest action, i.e. of the half-width
    ``(high - low) / 2`` of the action box in each dimension (``high`` for a
    symmetric box).
    """

    gamma: float = 0.99
    """Discount factor gamma of the TD target, eq. (5)."""
    tau: float = 0.005
    """Polyak rate of the target networks: theta' <- tau * theta + (1 - tau) * theta'."""
    policy_noise: float = 0.2
    """Std of the target-policy smoothing noise, as a fraction of max action."""
    noise_clip: float = 0.5
    """Target-policy smoothing noise is clipped to +-noise_clip, a fraction of max action."""
    policy_delay: int = 2
    """Actor and target networks are updated once every `policy_delay` critic updates."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 3e-4
    """Adam learning rate of the twin critic."""
    hidden_sizes: tuple[int, ...] = (256, 256)
    """Widths of the hidden ReLU layers of the actor and of each critic."""
    critic_layer_norm: str | bool = "none"
    """Where the twin critics get a LayerNorm before a hidden ReLU: ``none``, ``first``
    (the first hidden layer only), ``all`` (each, RLPD's critic, Ball et al., 2023) or
    ``auto`` (``all`` where the observation space leaves a bound open, ``none`` where every
    bound is finite: `learner.td3.builder.critic_layer_norm_for`); a bool reads as
    ``all``/``none``. The actor stays a plain MLP."""
    standardize_observations: bool = False
    """The actor and the critics centre each observation feature on its mean and divide
    it by its standard deviation where that exceeds 1, both measured on the first batch the
    learner trains on (the warm-up data) and fixed from then on
    (`learner.td3.networks.fit_standardizers`); they travel with the weights."""
    batch_size: int = 256
    """Transitions per learner update (sampled by the learner loop, not by `update`)."""
    exploration_noise: float = 0.1
    """Std of the behaviour noise actors add to pi(s), as a fraction of max action."""
    frozen_actor_updates: int = 0
    """Initial updates during which the actor is not trained (paper, fig. 3); targets still move."""
    burn_in_updates: int = 0
    """Extra updates on the first `learning_starts` steps, before the actors go on (with
    `frozen_actor_updates` >= it: a critic burn-in on the warm-up data, e.g. the backbone's
    prefill). Counted in updates, not env steps."""

    def standardized(self, obs_dim: int) -> int:
        """How many leading inputs the networks standardize: the observation's `obs_dim`
        with `standardize_observations`, none without."""
        return obs_dim if self.standardize_observations else 0

    def __post_init__(self) -> None:
        """Refuses settings that cannot train, with a message naming the field."""
        # Presets parsed from YAML give lists; keep the dataclass hashable and immutable.
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
        object.__setattr__(self, "critic_layer_norm", layer_norm_setting(self.critic_layer_norm))
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"gamma={self.gamma} must lie in [0, 1]; it discounts future reward.")
        if not 0.0 < self.tau <= 1.0:
            raise ValueError(
                f"tau={self.tau} must lie in (0, 1]: 0 would freeze the target networks forever, "
                "1 copies the online networks every delayed step."
            )
        for name in ("policy_noise", "noise_clip", "exploration_noise"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name}={getattr(self, name)} is a std/bound and must be >= 0.")
        if self.policy_delay < 1:
            raise ValueError(
                f"policy_delay={self.policy_delay} must be >= 1 (1 updates the actor every step)."
            )
        for name in ("actor_lr", "critic_lr"):
            if getattr(self, name) <= 0.0:
                raise ValueError(f"{name}={getattr(self, name)} must be > 0.")
        if not self.hidden_sizes or any(h < 1 for h in self.hidden_sizes):
            raise ValueError(
                f"hidden_sizes={self.hidden_sizes} must be a non-empty tuple of positive widths."
            )
        if self.batch_size < 1:
            raise ValueError(f"batch_size={self.batch_size} must be >= 1.")
        if self.burn_in_updates < 0:
            raise ValueError(
                f"burn_in_updates={self.burn_in_updates} must be >= 0 (0 disables it)."
            )
        if self.frozen_actor_updates < 0:
            raise ValueError(
                f"frozen_actor_updates={self.frozen_actor_updates} must be >= 0 (0 disables it)."
            )
