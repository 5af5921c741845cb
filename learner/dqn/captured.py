"""Double DQN's update as one captured step (`learner.captured`): the target, the Huber
(and large-margin) loss, clipping, Adam at the scheduled rate and the target network's
averaging, with the update count, the rate and the margin's weight on the device.

What the host still decides is known there without a sync: whether this update adds the
large-margin loss and whether the target moves (each a graph of its own).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import torch

from learner.captured import DeviceAdam, DeviceMetrics, StepGraph, host_state
from service.core import Metrics, TensorBatch

if TYPE_CHECKING:
    from learner.dqn.learning import DQNLearner


def clipped(grads: tuple[torch.Tensor, ...], max_norm: float) -> list[torch.Tensor]:
    """`grads` scaled to a total norm of at most `max_norm`, as `nn.utils.clip_grad_norm_`
    scales parameters' gradients (its 1e-6 included)."""
    norms = torch._foreach_norm(list(grads))
    total = torch.linalg.vector_norm(torch.stack(norms))
    coef = torch.clamp(max_norm / (total + 1e-6), max=1.0)
    return list(torch._foreach_mul(list(grads), coef))


def scheduled(
    start: float, end: Optional[float], *, step: torch.Tensor, steps: int
) -> torch.Tensor:
    """`linear_decay` at a device step: start + (end − start) · min(step / steps, 1)."""
    if end is None:
        return torch.full_like(step, start)
    return start + (end - start) * torch.clamp(step / max(steps, 1), max=1.0)


def margin_weight_at(u: torch.Tensor, *, burn_in: int, total: int, after: bool) -> torch.Tensor:
    """`margin_weight` at a device update count `u`."""
    one, zero = torch.ones_like(u), torch.zeros_like(u)
    decayed = (1.0 - (u - burn_in) / max(total - burn_in, 1)) if after else zero
    later = torch.where(u < total, decayed, zero)
    return torch.where(u < burn_in, one, later)


class CapturedDQN:
    """Runs a `DQNLearner`'s updates as captured steps; `fit` is the step's body, which the
    option learner's captured step reuses with a device flag (`enabled`)."""

    def __init__(self, learner: DQNLearner, *, compiled: Optional[str] = None) -> None:
        self.learner, self.compiled = learner, compiled
        self.adam = DeviceAdam(learner.optimizer.optimizer, device=learner.device)
        self.count = torch.tensor(float(learner.num_updates), device=learner.device)
        """Updates so far, on the device (the rate and the margin follow it)."""
        self.metrics = DeviceMetrics(learner.device)
        self._graphs: dict[tuple[bool, bool], StepGraph] = {}
        self._pinned: dict[str, torch.Tensor] = {}

    def step(self, batch: TensorBatch) -> Metrics:
        """One update on `batch` (its columns as `DQNLearner.update` takes them)."""
        learner = self.learner
        key = (learner._with_margin(), (learner.num_updates + 1) % learner._target_every == 0)
        if key not in self._graphs:
            self._graphs[key] = StepGraph(
                lambda inputs: self._step(inputs, expert=key[0], move_target=key[1]),
                device=learner.device,
                metrics=[self.metrics],
                compiled=self.compiled,
            )
        graph = self._graphs[key]
        graph.load("", batch)
        graph.run()
        learner.num_updates += 1
        return {}

    def _step(self, batch: TensorBatch, *, expert: bool, move_target: bool) -> None:
        obs, action, y, expert_action, weight = self.learner.fit_inputs(batch, expert=expert)
        self.fit(obs, action, y, expert_action=expert_action, weight=weight)
        if move_target:
            self.move_target(None)

    def fit(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        y: torch.Tensor,
        *,
        expert_action: Optional[torch.Tensor] = None,
        weight: Optional[torch.Tensor] = None,
        enabled: Optional[torch.Tensor] = None,
        names: tuple[str, str] = ("losses/q", "values/q_mean"),
    ) -> None:
        """`DQNLearner.fit` in tensors; with `enabled` (a device bool) nothing changes where
        it is false (an update without rows)."""
        from learner.dqn.learning import mean_over

        learner, u = self.learner, self.count
        margin = margin_weight_at(
            u,
            burn_in=learner._margin_updates,
            total=learner._total_updates or 0,
            after=learner._margin_after,
        )
        loss, q, margin_loss = learner.loss(
            obs, action, y, expert_action, weight, margin_weight=margin
        )
        grads = clipped(torch.autograd.grad(loss, self.adam.params), learner._max_grad_norm)
        total = learner._total_updates or 0
        lr = scheduled(learner._lr_start, learner._lr_end, step=u, steps=total)
        self.adam.lr.copy_(lr)
        self.adam.step(grads, enabled=enabled)
        u.add_(1.0 if enabled is None else enabled.to(u.dtype))
        self.metrics.add(names[0], loss, enabled)
        self.metrics.add(names[1], mean_over(q.detach(), weight), enabled)
        if names[0] == "losses/q":
            self.metrics.add("charts/learning_rate", lr, enabled)
        if margin_loss is not None:
            self.metrics.add("losses/margin", margin_loss, enabled)

    @torch.no_grad()
    def move_target(self, due: Optional[torch.Tensor]) -> None:
        """Polyak averaging of the target network; `due` (a device bool) gates it."""
        learner = self.learner
        tau = learner._target_tau
        targets: list[torch.Tensor] = list(learner.target_q.parameters())
        sources: list[torch.Tensor] = list(learner.q.parameters())
        if due is None:
            torch._foreach_lerp_(targets, sources, tau)
            return
        weight = due.to(torch.float32) * tau
        for target, source in zip(targets, sources, strict=True):
            target.lerp_(source, weight)

    def read_metrics(self) -> dict[str, float]:
        return self.metrics.read()

    def policy_state(self) -> dict[str, torch.Tensor]:
        """The Q network's weights on the host (pinned, asynchronous copies on CUDA)."""
        return host_state(self.learner.q.state_dict(), self._pinned)
