"""Hyper-parameters of pre-training TD3 from a hard-coded policy (sec. III-A)."""

from __future__ import annotations

from dataclasses import dataclass

PRETRAIN_LOSSES = ("td3", "bc_td", "td3_bc")
ONLINE_LOSSES = ("td3", "td3_bc")


@dataclass(frozen=True)
class PretrainConfig:
    """How the demonstrations are collected and what is learned from them."""

    demo_steps: int = 10_000
    """N: transitions collected with μ(s) + N(0, σ²) before any learning (paper: 10,000)."""
    demo_noise: float = 0.5
    """σ of the demonstration noise (action units); fig. 2 sweeps it."""
    pretrain_updates: int = 20_000
    """Learner updates on the demonstrations before online training (paper fig. 2: 20k)."""
    pretrain_loss: str = "bc_td"
    """td3: plain TD3 offline (fig. 2); bc_td: actor eq. (8), critic eq. (9) (fig. 3);
    td3_bc: TD3+BC (Fujimoto & Gu 2021)."""
    online_loss: str = "td3"
    """td3: standard TD3 after pre-training; td3_bc: keep the BC term towards μ(s)."""
    bc_alpha: float = 2.5
    """TD3+BC's α: the actor maximises λQ − (π(s) − μ(s))², λ = α / mean|Q|."""

    def __post_init__(self) -> None:
        if self.demo_steps < 1 or self.pretrain_updates < 0:
            raise ValueError("demo_steps must be >= 1 and pretrain_updates >= 0")
        if not self.demo_noise > 0.0:
            raise ValueError(f"demo_noise={self.demo_noise} must be > 0 (log_prob needs it)")
        if self.pretrain_loss not in PRETRAIN_LOSSES:
            raise ValueError(f"pretrain_loss={self.pretrain_loss!r}; choose from {PRETRAIN_LOSSES}")
        if self.online_loss not in ONLINE_LOSSES:
            raise ValueError(f"online_loss={self.online_loss!r}; choose from {ONLINE_LOSSES}")
        if not self.bc_alpha > 0.0:
            raise ValueError(f"bc_alpha={self.bc_alpha} must be > 0")
