"""TD3's update as captured steps (`learner.captured`): one step function per delay
cycle, the policy delay unrolled in it, so nothing branches on a device value.

A cycle of d = ``policy_delay`` updates is d critic steps, each on its own batch and its
own smoothing noise, then (unless the actor is still frozen: a second graph) the actor's
step on the last batch, then Polyak averaging of both targets: the order in which the
eager `TD3Learner._step` runs them. The learner's hooks (`_critic_target`,
`_critic_baseline`, `_actor_loss`, `_observe`, `_ramp_range`) are called inside, so every
learner built on TD3 (pre-training, backbone, teacher, Retrace) captures the same way.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import torch

from learner.captured import DeviceAdam, DeviceMetrics, NoiseSource, StepGraph, host_state
from service.core import Metrics, TensorBatch

if TYPE_CHECKING:
    from learner.td3.learning import TD3Learner


def critic_step(
    learner: TD3Learner, batch: TensorBatch, adam: DeviceAdam, metrics: DeviceMetrics
) -> None:
    """One critic step (eq. 9) on `batch`, as `TD3Learner._step` takes it."""
    from learner.td3.learning import critic_loss

    batch = learner._observe(batch)
    obs = batch["obs"]
    # The stored action is the unclipped sampled one; the critic values the applied one.
    action = torch.clamp(batch["action"], *learner.action_box)
    target = learner._critic_target(batch)
    q1, q2 = learner.critic(obs, action)
    baseline = learner._critic_baseline(batch)
    if baseline is not None:
        q1, q2 = q1 + baseline, q2 + baseline
    weight = batch.get("_rows")
    loss = critic_loss(q1, q2, target) if weight is None else _masked_loss(q1, q2, target, weight)
    adam.step(torch.autograd.grad(loss, adam.params), enabled=batch.get("_enabled"))
    metrics.add("losses/critic", loss, batch.get("_enabled"))
    metrics.add("values/q1_mean", _mean(q1.detach(), weight), batch.get("_enabled"))


def _mean(values: torch.Tensor, weight: Optional[torch.Tensor]) -> torch.Tensor:
    if weight is None:
        return values.mean()
    return (values * weight).sum() / weight.sum().clamp_min(1.0)


def _masked_loss(
    q1: torch.Tensor, q2: torch.Tensor, target: torch.Tensor, weight: torch.Tensor
) -> torch.Tensor:
    """Eq. (9) over the rows `weight` keeps (0 or 1): the batch keeps its shape."""
    return _mean((q1 - target) ** 2, weight) + _mean((q2 - target) ** 2, weight)


def actor_step(
    learner: TD3Learner,
    batch: TensorBatch,
    adam: DeviceAdam,
    metrics: DeviceMetrics,
    *,
    count: torch.Tensor,
    enabled: Optional[torch.Tensor] = None,
) -> None:
    """The delayed actor step on `batch`; `count` (on the device) counts actor steps."""
    batch = learner._observe(batch)
    learner._ramp_range(count)
    loss = learner._actor_loss(batch["obs"], batch)
    adam.step(torch.autograd.grad(loss, adam.params), enabled=enabled)
    count.add_(1 if enabled is None else enabled.to(count.dtype))
    metrics.add("losses/actor", loss, enabled)


class CapturedTD3:
    """Runs a `TD3Learner`'s updates as captured cycles.

    Each update's batch is loaded into its slot of the cycle at once (one copy on CUDA);
    the cycle runs when its last slot is loaded. The learner's counters move per update
    as they always did; the weights catch up at the cycle's end, or at `settle` (before
    weights are published or saved), which runs the loaded slots' critic steps eagerly.
    """

    def __init__(self, learner: TD3Learner, *, compiled: Optional[str] = None) -> None:
        self.learner, self.compiled = learner, compiled
        device = learner.device
        self.critic_adam = DeviceAdam(learner.critic_optimizer.optimizer, device=device)
        self.actor_adam = DeviceAdam(learner.actor_optimizer.optimizer, device=device)
        self.noise = NoiseSource(learner._generator, device)
        self.metrics = DeviceMetrics(device)
        self.actor_count = torch.tensor(learner.num_actor_updates, device=device)
        self.delay = learner._policy_delay
        self._graphs: dict[tuple[object, bool], StepGraph] = {}
        self._loaded: Optional[StepGraph] = None
        self._key: object = None
        self._slots: list[int] = []
        """The slots loaded and not yet applied."""
        self._pinned: dict[str, torch.Tensor] = {}

    def _graph(self, key: object, train_actor: bool) -> StepGraph:
        if (key, train_actor) not in self._graphs:
            self._graphs[(key, train_actor)] = StepGraph(
                lambda inputs: self._cycle(inputs, train_actor=train_actor),
                device=self.learner.device,
                metrics=[self.metrics],
                sources=[self.noise],
                compiled=self.compiled,
            )
        return self._graphs[(key, train_actor)]

    def _slot(self, inputs: dict[str, torch.Tensor], i: int) -> TensorBatch:
        prefix = f"{i}/"
        return {k[len(prefix) :]: v for k, v in inputs.items() if k.startswith(prefix)}

    def _cycle(self, inputs: dict[str, torch.Tensor], *, train_actor: bool) -> None:
        """The step function: d critic steps, the actor's, both targets' averaging."""
        from learner.td3.learning import soft_update

        learner = self.learner
        for i in range(self.delay):
            critic_step(learner, self._slot(inputs, i), self.critic_adam, self.metrics)
        last = self._slot(inputs, self.delay - 1)
        if train_actor:
            actor_step(learner, last, self.actor_adam, self.metrics, count=self.actor_count)
        soft_update(learner.target_critic, learner.critic, learner._tau)
        soft_update(learner.target_actor, learner.actor, learner._tau)

    def step(self, batch: TensorBatch, *, step: int, train_actor: bool, key: object) -> Metrics:
        """Update `step` of the counter `key` (online or pre-training) on `batch`."""
        if key != self._key:
            self.settle()
            self._key = key
        slot = (step - 1) % self.delay
        graph = self._graph(key, train_actor)
        if self._loaded is not None and self._loaded is not graph:
            self._move_loaded(graph)
        graph.load(f"{slot}/", batch)
        self._loaded = graph
        self._slots.append(slot)
        if slot == self.delay - 1:
            if self._slots == list(range(self.delay)):
                graph.run()
            else:  # the cycle's first slots were settled on their own: finish it eagerly
                self._eager(graph, self._slots, finish=True, train_actor=train_actor)
            self._slots = []
        if train_actor and step % self.delay == 0:
            self.learner.num_actor_updates += 1
        return {}

    def _move_loaded(self, graph: StepGraph) -> None:
        """The loaded slots into `graph` (the actor's freeze ended inside a cycle)."""
        assert self._loaded is not None
        for slot in self._slots:
            graph.load(f"{slot}/", self._slot(self._loaded.inputs, slot))

    def _eager(
        self, graph: StepGraph, slots: list[int], *, finish: bool, train_actor: bool
    ) -> None:
        """The slots' steps run eagerly on the graph's inputs (and the cycle's end)."""
        from learner.td3.learning import soft_update

        learner = self.learner
        for slot in slots:
            critic_step(learner, self._slot(graph.inputs, slot), self.critic_adam, self.metrics)
        if finish:
            last = self._slot(graph.inputs, self.delay - 1)
            if train_actor:
                actor_step(learner, last, self.actor_adam, self.metrics, count=self.actor_count)
            soft_update(learner.target_critic, learner.critic, learner._tau)
            soft_update(learner.target_actor, learner.actor, learner._tau)
        self.metrics.flush()

    def settle(self) -> None:
        """Applies the loaded slots of an unfinished cycle (critic steps only: the actor
        and the targets move at its end)."""
        if self._slots and self._loaded is not None:
            self._eager(self._loaded, self._slots, finish=False, train_actor=False)
        self._slots = []

    def read_metrics(self) -> dict[str, float]:
        return self.metrics.read()

    def policy_state(self) -> dict[str, torch.Tensor]:
        """The actor's weights on the host (pinned, asynchronous copies on CUDA)."""
        self.settle()
        return host_state(self.learner.actor.state_dict(), self._pinned)
