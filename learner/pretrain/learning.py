"""Pre-training TD3 from demonstrations: imitation (eq. 8), TD (eq. 9), TD3+BC.

`pretrain_update` runs on the demonstration table, `update` online; both are TD3's
critic step (eq. 9 is TD3's target with the next action from the training policy π)
and differ in the actor's objective:

- td3:    −Q1(s, π(s))                                     (fully offline TD3, fig. 2)
- bc_td:  Σ (μ(s) − π(s))²                                 (eq. 8, fig. 3)
- td3_bc: −λ Q1(s, π(s)) + (π(s) − μ(s))², λ = α / mean|Q1| (Fujimoto & Gu 2021)

μ(s) is the hard-coded action the actor recorded in ``backbone_action``: we imitate the
clean hard-coded policy, not its noisy demonstrations.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from learner.device import CPU, CompileMode
from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner, actor_loss
from service.core import Algorithm, Metrics, TensorBatch


def imitation_loss(policy_action: torch.Tensor, hardcoded_action: torch.Tensor) -> torch.Tensor:
    """Eq. (8), as a mean over the batch: mean_n Σ_j (μ(s_n)_j − π(s_n)_j)²."""
    return (hardcoded_action - policy_action).pow(2).sum(dim=-1).mean()


def td3_bc_actor_loss(
    q: torch.Tensor, policy_action: torch.Tensor, hardcoded_action: torch.Tensor, *, alpha: float
) -> torch.Tensor:
    """TD3+BC's actor loss: −λ mean Q + mean (π(s) − μ(s))², λ = α / mean|Q| (no gradient)."""
    lam = alpha / q.abs().mean().detach().clamp_min(1e-6)
    return -lam * q.mean() + F.mse_loss(policy_action, hardcoded_action)


class PretrainLearner(TD3Learner):
    """TD3 with a pre-training step and a choice of actor objective per phase."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        *,
        config: TD3Config,
        seed: int,
        pretrain_loss: str,
        online_loss: str,
        bc_alpha: float,
        device: torch.device = CPU,
        compile: CompileMode = "off",
    ) -> None:
        super().__init__(
            obs_dim,
            act_dim,
            action_low,
            action_high,
            config=config,
            seed=seed,
            device=device,
            compile=compile,
        )
        self._losses = {"pretrain": pretrain_loss, "online": online_loss}
        self._objective = pretrain_loss
        self._bc_alpha = bc_alpha
        self.num_pretrain_updates = 0

    def pretrain_update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """One step on the demonstrations; the online counters (and actor freeze) wait."""
        self._objective = self._losses["pretrain"]
        self.num_pretrain_updates += 1
        return self._step(batch, step=self.num_pretrain_updates, train_actor=True, key="pretrain")

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """One online TD3 step; `frozen_actor_updates` counts from the first of these."""
        self._objective = self._losses["online"]
        return super().update(batch)

    def _actor_loss(self, obs: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if self._objective == "td3":
            return actor_loss(self.critic, self.actor, obs)
        policy_action = self.actor(obs)
        hardcoded_action = batch["backbone_action"].to(self.device)
        if self._objective == "bc_td":
            return imitation_loss(policy_action, hardcoded_action)
        q = self.critic.q1(obs, policy_action)
        return td3_bc_actor_loss(q, policy_action, hardcoded_action, alpha=self._bc_alpha)

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "num_pretrain_updates": self.num_pretrain_updates}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.num_pretrain_updates = int(state.get("num_pretrain_updates", 0))


def pretrain_step(algorithm: Algorithm, batch: TensorBatch) -> Metrics:
    """The demonstration phase's step: `PretrainLearner.pretrain_update`."""
    if not isinstance(algorithm, PretrainLearner):
        raise TypeError(f"pre-training needs a PretrainLearner, got {type(algorithm).__name__}")
    return algorithm.pretrain_update(batch)
