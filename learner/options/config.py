"""Hyper-parameters of the hierarchical options method (sec. III-C) beyond DQN's and TD3's."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class OptionsConfig:
    """Options {hard-coded, RL}; the option values use `DQNConfig`, the RL option `TD3Config`."""

    option_length: int = 10
    """k: steps an option runs once chosen; also the replay window length."""
    retrace_lambda: float = 1.0
    """λ of the Retrace traces c = λ · min(1, ρ), eq. (14)."""

    def __post_init__(self) -> None:
        if self.option_length < 1:
            raise ValueError(f"option_length={self.option_length} must be >= 1")
        if not 0.0 <= self.retrace_lambda <= 1.0:
            raise ValueError(f"retrace_lambda={self.retrace_lambda} must lie in [0, 1]")
