"""Hyper-parameters of the hierarchical options method (sec. III-C) beyond DQN's and TD3's."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class OptionsConfig:
    """Options {hard-coded, RL}; the option values use `DQNConfig`, the RL option `TD3Config`."""

    option_length: int = 10
    """k: steps an option runs once chosen; also the replay window length."""
    retrace_lambda: float = 1.0
    """λ of the Retrace traces c = λ · min(1, ρ), eq. (14)."""
    residual_limit: Optional[float] = None
    """L of a residual RL option, μ(s) + clip(π([s, μ(s)]), [−L, L]) with π zero at the
    start (None: the paper's RL option, π(s) alone from a random initialisation)."""
    switch_margin: float = 0.0
    """m: the policy over options picks the RL option only where its value beats the
    hard-coded option's by more than m (0: plain argmax, as in the paper)."""
    intra_option: bool = False
    """Intra-option learning: the RL option's critic learns from every transition, tree
    steps included, with TD3's one-step target (False: Retrace, eq. 14, on its own steps)."""

    def __post_init__(self) -> None:
        if self.option_length < 1:
            raise ValueError(f"option_length={self.option_length} must be >= 1")
        if not 0.0 <= self.retrace_lambda <= 1.0:
            raise ValueError(f"retrace_lambda={self.retrace_lambda} must lie in [0, 1]")
        if self.residual_limit is not None and not self.residual_limit > 0.0:
            raise ValueError(
                f"residual_limit={self.residual_limit} must be > 0 (or null for the paper's "
                "RL option): the correction range [-L, L] would be empty"
            )
        if self.switch_margin < 0.0:
            raise ValueError(f"switch_margin={self.switch_margin} must be >= 0")
