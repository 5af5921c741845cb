"""Backbone TD3 learning: TD3 on the correction, plus the teacher target of eq. (11).

Without a teacher the learner is plain TD3 whose action box is the correction range
[−L, L] and whose critic values (s, π(s)) (sec. III-B): the replay column ``action``
holds the sampled correction. With a teacher (μ̂, Q̂) the critic learns to correct Q̂:
its prediction is Q̂(s, μ̂(s)) + Q_θ(s, c) and its target is eq. (11).
"""

from __future__ import annotations

import copy
from typing import Any, Optional

import numpy as np
import torch
from torch import nn

from actors.behaviours.switching import CRITIC_PREFIX
from learner.backbone.networks import backbone_input
from learner.device import CPU, CompileMode, compile_networks
from learner.pretrain.learning import imitation_loss
from learner.selection import with_tree_only
from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner, td3_target
from learner.td3.networks import Actor, TwinCritic


def teacher_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    *,
    gamma: float,
    teacher_next_value: torch.Tensor,
    next_correction_value: torch.Tensor,
) -> torch.Tensor:
    """Eq. (11): y = r + γ (Q̂(s', μ̂(s')) + Q_θ(s', π_φ(s'))), no bootstrap past a terminal.

    Args:
        reward: r, [B].
        terminated: [B] bool; a time-limit truncation is not termination.
        gamma: Discount.
        teacher_next_value: Q̂(s', μ̂(s')), [B].
        next_correction_value: Q_θ(s', π_φ(s')) from the target networks, [B].

    Returns:
        y, [B].
    """
    not_done = 1.0 - terminated.to(reward.dtype)
    return reward + gamma * not_done * (teacher_next_value + next_correction_value)


def ibrl_target(
    reward: torch.Tensor,
    terminated: torch.Tensor,
    *,
    gamma: float,
    next_policy_value: torch.Tensor,
    next_tree_value: torch.Tensor,
) -> torch.Tensor:
    """IBRL's target (Hu et al. 2023, eq. 3): y = r + γ max(Q'(s', π'(s')), Q'(s', μ(s'))),
    no bootstrap past a terminal (a time-limit truncation is not one).

    Args:
        reward: r, [B].
        terminated: [B] bool.
        gamma: Discount.
        next_policy_value: min(Q1', Q2')(s', π'(s') + smoothing noise), [B].
        next_tree_value: min(Q1', Q2')(s', μ(s')), [B] (the residual's correction 0, a
            standalone actor's μ(s') − centre).

    Returns:
        y, [B].
    """
    not_done = 1.0 - terminated.to(reward.dtype)
    return reward + gamma * not_done * torch.maximum(next_policy_value, next_tree_value)


def conservative_actor_loss(
    critic: TwinCritic,
    actor: nn.Module,
    obs: torch.Tensor,
    *,
    bound: torch.Tensor,
    penalty: float,
) -> torch.Tensor:
    """The actor's loss kept near the backbone: −Q1(s, c) / mean|Q1| + β · mean((c / L)²),
    c = π(s). Normalising Q by its mean magnitude (no gradient through it) makes β mean
    the same on every task, whatever the scale of its returns (TD3+BC, Fujimoto & Gu 2021).

    Args:
        critic: The online twin critic; only its first head is used.
        actor: The correction π.
        obs: s (with μ(s) appended), [B, obs_dim].
        bound: L per action dimension, [act_dim].
        penalty: β >= 0.

    Returns:
        The scalar loss.
    """
    correction = actor(obs)
    q = critic.q1(obs, correction)
    scale = q.abs().mean().detach().clamp_min(1e-6)
    return -q.mean() / scale + penalty * ((correction / bound) ** 2).mean()


class ObservingBackboneLearner(TD3Learner):
    """TD3 on the correction whose actor and critics see [s, μ(s) / scale] (residual RL).

    The batches carry μ(s) (``backbone_action``) and μ(s') (``next_backbone_action``), as
    the actors recorded them; this learner appends them to ``obs`` and ``next_obs``.
    """

    def __init__(
        self,
        obs_dim: int,
        bound: np.ndarray,
        scale: np.ndarray,
        *,
        config: TD3Config,
        seed: int,
        device: torch.device = CPU,
        compile: CompileMode = "off",
        correction_penalty: float = 0.0,
        publish_critic: bool = False,
        ramp_actor_updates: int = 0,
        tree_in_target: bool = False,
        centre: Optional[np.ndarray] = None,
        clone_tree: bool = False,
        tree_input: bool = True,
    ) -> None:
        """`bound` is L per action dimension; `scale` the half-width of the action box;
        `correction_penalty` β of `conservative_actor_loss` (0: TD3's actor loss);
        `publish_critic`: the published weights carry the critic too (value-based
        switching in the behaviour); `ramp_actor_updates`: π's range grows linearly from
        0 to [−L, L] over its first that many gradient steps (0: the whole range at once);
        `tree_in_target`: the tree is a proposal in the TD target (`ibrl_target`);
        `centre`: a standalone actor, whose output is the action minus this centre, so
        that the tree's proposal is μ(s) − centre (None: the residual, the correction 0);
        `clone_tree`: while the actor is frozen, its delayed steps fit π(s) to the tree's
        proposal instead (eq. 8's `imitation_loss`; needs `centre`, and eager updates);
        `tree_input`: the networks see [s, μ(s) / scale] (False: s alone, the batches'
        μ(s) and μ(s') only the tree's proposal)."""
        act_dim = bound.shape[0]
        super().__init__(
            obs_dim,
            act_dim,
            -bound,
            bound,
            config=config,
            seed=seed,
            device=device,
            compile=compile,
            extra_inputs=act_dim if tree_input else 0,
        )
        self._tree_input = tree_input
        self._scale = torch.as_tensor(scale, dtype=torch.float32, device=self.device)
        self._bound = torch.tensor(bound, dtype=torch.float32, device=self.device)  # a copy
        self._penalty = correction_penalty
        self._publish_critic = publish_critic
        self._ramp = ramp_actor_updates
        self._tree_in_target = tree_in_target
        self._centre = (
            None if centre is None else torch.as_tensor(centre, dtype=torch.float32).to(self.device)
        )
        if clone_tree and centre is None:
            raise ValueError("clone_tree needs a standalone actor (centre): a residual is 0")
        if clone_tree and self.captures:
            raise ValueError(
                "backbone.clone_tree runs eager updates: learner.compile='captured' is not "
                "supported with it (choose another compile mode)"
            )
        self._clone = clone_tree
        if self._ramp:
            self._set_range()  # before the first step: π starts at the tree
        self.tree_only = False
        """Set by the final selection (`keep_tree`): the greedy policy is the tree alone."""

    def policy_state(self) -> dict[str, torch.Tensor]:
        """π's weights, the critic's (``critic.``-prefixed) when publishing it, and the
        tree-only flag: set by the final selection, and until π's first gradient step (an
        untrained π, valued by a critic that has seen only the tree's data, never acts
        greedily; exploration is not affected)."""
        state = super().policy_state()
        if self._publish_critic:
            for k, v in self.critic.state_dict().items():
                state[CRITIC_PREFIX + k] = v.detach().to("cpu", copy=True)
        return with_tree_only(state, self.tree_only or self.num_actor_updates == 0)

    def tree_state(self) -> dict[str, torch.Tensor]:
        """Published weights under which the greedy policy is the tree alone."""
        return with_tree_only(self.policy_state(), True)

    def keep_tree(self) -> None:
        """From now on the greedy policy (published and checkpointed) is the tree alone."""
        self.tree_only = True

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "tree_only": self.tree_only}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.tree_only = bool(state.get("tree_only", False))

    def _set_range(self) -> None:
        """π's range (the actor's and its target's squash bounds, published with the
        weights) at this point of the ramp: ±L · min(1, (actor steps + 1) / ramp)."""
        share = min(1.0, (self.num_actor_updates + 1) / self._ramp)
        for actor in (self.actor, self.target_actor):
            actor.action_high.copy_(self._bound * share)
            actor.action_low.copy_(-self._bound * share)

    def _actor_step(self, obs: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if self._ramp and self.num_actor_updates < self._ramp:
            self._set_range()
        return super()._actor_step(obs, batch)

    def _ramp_range(self, actor_steps: torch.Tensor) -> None:
        """`_set_range` inside a captured step, from the actor steps counted on the device
        (past the ramp it sets the whole range, as the last eager `_set_range` did)."""
        if self._ramp:
            share = torch.clamp((actor_steps + 1).to(torch.float32) / self._ramp, max=1.0)
            for actor in (self.actor, self.target_actor):
                actor.action_high.copy_(self._bound * share)
                actor.action_low.copy_(-self._bound * share)

    def _actor_loss(self, obs: torch.Tensor, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if self._penalty == 0.0:
            return super()._actor_loss(obs, batch)
        return conservative_actor_loss(
            self.critic, self.actor, obs, bound=self._bound, penalty=self._penalty
        )

    def _step(
        self, batch: dict[str, torch.Tensor], *, step: int, train_actor: bool, key: str = "online"
    ) -> dict[str, float]:
        metrics = super()._step(batch, step=step, train_actor=train_actor, key=key)
        if self._clone and not train_actor and step % self._policy_delay == 0:
            metrics["losses/clone"] = self._clone_step(batch)
        return metrics

    def _clone_step(self, batch: dict[str, torch.Tensor]) -> float:
        """One gradient step of π towards the tree's proposal on this (observed) batch."""
        obs = batch["obs"].to(self.device, non_blocking=True)
        loss = imitation_loss(self.actor(obs), self._tree_proposal(batch, "backbone_action"))
        self.actor_optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.actor_optimizer.step()
        return float(loss.detach())

    def _critic_target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        if not self._tree_in_target:
            return super()._critic_target(batch)
        dev = self.device
        reward = batch["reward"].to(dev, non_blocking=True)
        terminated = batch["terminated"].to(dev, non_blocking=True)
        next_obs = batch["next_obs"].to(dev, non_blocking=True)
        # min(Q1', Q2')(s', π'(s') + smoothing): TD3's target with r = 0, γ = 1, no terminal.
        next_policy_value = td3_target(
            torch.zeros_like(reward),
            torch.zeros_like(terminated),
            next_obs,
            gamma=1.0,
            **self._smoothing(),
        )
        with torch.no_grad():
            tree = self._tree_proposal(batch, "next_backbone_action")
            next_tree_value = torch.min(*self.target_critic(next_obs, tree))
        return ibrl_target(
            reward,
            terminated,
            gamma=self._gamma,
            next_policy_value=next_policy_value,
            next_tree_value=next_tree_value,
        )

    def _tree_proposal(self, batch: dict[str, torch.Tensor], column: str) -> torch.Tensor:
        """The tree's action in `column` (μ(s) or μ(s')) as π's output, [B, A]: μ + 0, the
        correction 0 (residual), or a standalone actor's μ − centre, in the box the critic
        values."""
        if self._centre is None:
            return torch.zeros(len(batch["next_obs"]), len(self._bound), device=self.device)
        mu = batch[column].to(self.device, non_blocking=True)
        return torch.clamp(mu - self._centre, *self.action_box)

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        for name in ("backbone_action", "next_backbone_action"):
            if name not in batch:
                raise ValueError(
                    f"batch has no {name!r} column: actors of a backbone run with "
                    "observe_backbone=True record it (a table written by another run?)"
                )
        if self.captures:  # the captured step makes the inputs itself (`_observe`)
            return super().update(batch)
        return super().update(self._observe(batch))

    def _observe(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """[s, μ(s) / scale] and [s', μ(s') / scale] in place of ``obs`` and ``next_obs``
        (without `tree_input`, the batch as it is)."""
        if not self._tree_input:
            return batch
        return dict(
            batch,
            obs=backbone_input(batch["obs"], batch["backbone_action"], self._scale),
            next_obs=backbone_input(batch["next_obs"], batch["next_backbone_action"], self._scale),
        )


class TeacherBackboneLearner(TD3Learner):
    """TD3 on the correction of a trained teacher (μ̂, Q̂), eq. (11)."""

    def __init__(
        self,
        obs_dim: int,
        limit: float,
        *,
        teacher: tuple[Actor, TwinCritic],
        config: TD3Config,
        seed: int,
        device: torch.device = CPU,
        compile: CompileMode = "off",
    ) -> None:
        """The teacher is copied onto the learner's device (the actors keep theirs)."""
        act_dim = teacher[0].action_low.shape[0]
        bound = np.full(act_dim, limit, dtype=np.float32)
        super().__init__(
            obs_dim,
            act_dim,
            -bound,
            bound,
            config=config,
            seed=seed,
            device=device,
            compile=compile,
        )
        self.teacher_actor = copy.deepcopy(teacher[0]).to(self.device)
        self.teacher_critic = copy.deepcopy(teacher[1]).to(self.device)
        compile_networks([self.teacher_actor, self.teacher_critic], compile)

    @torch.no_grad()
    def _teacher_value(self, obs: torch.Tensor) -> torch.Tensor:
        """Q̂(s, μ̂(s)), the smaller of the teacher's twin estimates."""
        return torch.min(*self.teacher_critic(obs, self.teacher_actor(obs)))

    def _critic_target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        reward, terminated = batch["reward"], batch["terminated"]
        # Q_θ(s', π'(s') + smoothing): TD3's target with r = 0, γ = 1 and no terminal.
        next_correction_value = td3_target(
            torch.zeros_like(reward),
            torch.zeros_like(terminated),
            batch["next_obs"],
            gamma=1.0,
            **self._smoothing(),
        )
        return teacher_target(
            reward,
            terminated,
            gamma=self._gamma,
            teacher_next_value=self._teacher_value(batch["next_obs"]),
            next_correction_value=next_correction_value,
        )

    def _critic_baseline(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        # The critic learns the correction to Q̂: its estimate of the return is the sum.
        return self._teacher_value(batch["obs"])
