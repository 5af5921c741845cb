"""Hyper-parameters of Double DQN, as one frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

WARMUPS = ("uniform", "hardcoded")


@dataclass(frozen=True)
class DQNConfig:
    """Double DQN hyper-parameters (sec. II-B1); also the policy-over-options learner."""

    gamma: float = 0.99
    """Discount factor of the target, eq. (4)."""
    learning_rate: float = 1e-3
    """Adam learning rate of the Q network (at the first update)."""
    learning_rate_end: Optional[float] = None
    """Learning rate at the run's last update: it decays linearly from `learning_rate`
    over the run's updates (None: constant). A rate near 0 at the end keeps the final
    policy from oscillating, as DQN on CartPole does at a constant rate."""
    hidden_sizes: tuple[int, ...] = (128, 128)
    """Widths of the hidden ReLU layers of the Q network."""
    batch_size: int = 64
    """Transitions per learner update."""
    target_update_every: int = 200
    """Updates between target-network updates."""
    target_tau: float = 1.0
    """Polyak rate of each target update: 1 copies the online network (DQN's hard update),
    e.g. 0.005 with target_update_every=1 moves the target smoothly."""
    n_step: int = 1
    """n of the n-step return: the learner samples windows of n consecutive steps from
    replay and trains every step of a window on its return to the window's end (1: the
    one-step target of eq. 4)."""
    max_grad_norm: float = 10.0
    """Gradients are clipped to this global norm (Huber loss keeps them bounded too)."""
    epsilon_start: float = 1.0
    """ε of the ε-greedy behaviour at the first policy step."""
    epsilon_end: float = 0.05
    """ε after the decay."""
    epsilon_decay_env_steps: int = 10_000
    """Env steps (over all actors) over which ε decays linearly."""
    warmup: str = "uniform"
    """How the first `learning_starts` env steps act: uniform (ε = 1), or hardcoded: the
    preset's hardcoded_policy μ, ε-greedy around μ(s) with `demo_epsilon` (demonstrations,
    as DQfD's; ddqn only)."""
    demo_epsilon: float = 0.1
    """Probability of a uniform action instead of μ(s) in the demonstrations (warmup: hardcoded)."""
    burn_in_updates: int = 0
    """Updates on the warm-up transitions alone before the actors go on (0: none)."""
    margin: float = 0.8
    """With warmup: hardcoded, the burn-in updates add DQfD's large-margin loss
    max_a [Q(s, a) + margin·1(a ≠ μ(s))] − Q(s, μ(s)), so that Q ranks μ's action first
    (Hester et al. 2018, eq. 2; 0 disables it)."""
    margin_after_burn_in: bool = False
    """Keep the large-margin loss after the burn-in, its weight decaying linearly from 1 to
    0 at the run's last update (`margin_weight`), so that Q leaves μ's ranking only as
    fast as the TD error pulls it away; False: the burn-in only."""
    switch_margin: Optional[float] = None
    """Value-based switching (warmup: hardcoded): the greedy policy acts argmax_a Q(s, a)
    only where Q(s, a) > Q(s, μ(s)) + margin · |Q(s, μ(s))|, else μ(s)
    (`actors.behaviours.switching`). None: plain argmax."""

    def __post_init__(self) -> None:
        """Refuses settings that cannot train, naming the field."""
        object.__setattr__(self, "hidden_sizes", tuple(int(h) for h in self.hidden_sizes))
        if not 0.0 <= self.gamma <= 1.0:
            raise ValueError(f"gamma={self.gamma} must lie in [0, 1]")
        if self.learning_rate <= 0.0 or self.max_grad_norm <= 0.0:
            raise ValueError("learning_rate and max_grad_norm must be > 0")
        if self.learning_rate_end is not None and not (
            0.0 <= self.learning_rate_end <= self.learning_rate
        ):
            raise ValueError(
                f"learning_rate_end={self.learning_rate_end} must lie in [0, learning_rate="
                f"{self.learning_rate}]: the schedule decays (None keeps the rate constant)"
            )
        if not self.hidden_sizes or any(h < 1 for h in self.hidden_sizes):
            raise ValueError(f"hidden_sizes={self.hidden_sizes} must be positive widths")
        if not 0.0 < self.target_tau <= 1.0:
            raise ValueError(f"target_tau={self.target_tau} must lie in (0, 1]")
        if self.n_step < 1:
            raise ValueError(f"n_step={self.n_step} must be >= 1")
        if self.batch_size < 1 or self.target_update_every < 1:
            raise ValueError("batch_size and target_update_every must be >= 1")
        if not 0.0 <= self.epsilon_end <= self.epsilon_start <= 1.0:
            raise ValueError(
                f"need 0 <= epsilon_end ({self.epsilon_end}) <= epsilon_start "
                f"({self.epsilon_start}) <= 1: ε is a probability and decays"
            )
        if self.warmup not in WARMUPS:
            raise ValueError(f"warmup={self.warmup!r} must be one of {', '.join(WARMUPS)}")
        if not 0.0 < self.demo_epsilon <= 1.0:
            raise ValueError(
                f"demo_epsilon={self.demo_epsilon} must lie in (0, 1]: the demonstrations "
                "need every action's probability > 0 (log_prob)"
            )
        if self.burn_in_updates < 0:
            raise ValueError(f"burn_in_updates={self.burn_in_updates} must be >= 0 (0: none)")
        if self.margin < 0.0:
            raise ValueError(f"margin={self.margin} must be >= 0 (0 disables the margin loss)")
        if self.switch_margin is not None and not self.switch_margin >= 0.0:
            raise ValueError(
                f"switch_margin={self.switch_margin} must be >= 0 (a fraction of "
                "|Q(s, μ(s))| the greedy action must gain), or null for no switching"
            )
        if (self.switch_margin is not None or self.margin_after_burn_in) and (
            self.warmup != "hardcoded"
        ):
            raise ValueError(
                "dqn.switch_margin and dqn.margin_after_burn_in compare with the hard-coded "
                f"policy's action: they need dqn.warmup: hardcoded (got {self.warmup!r})"
            )
        if self.epsilon_decay_env_steps < 1:
            raise ValueError(f"epsilon_decay_env_steps={self.epsilon_decay_env_steps} must be >= 1")
