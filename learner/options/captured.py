"""The option learner's update as one captured step (`learner.captured`).

The eager update selects rows (windows that start an option, the RL option's steps) and
skips a learner that gets none; a CUDA graph has fixed shapes and no host branch, so here
every window stays in and masks do the selecting: each loss is a mean over the rows its
mask keeps, and each learner's Adam step, counters and target averaging happen only where
its device flag (any row at all, the policy delay) is true. The counters live on the
device; `settle` brings them back to the learners before their state is read.

One difference from the eager update: intra-option learning draws the RL option's
smoothing noise for every pair of steps in the windows, kept or not (the eager update
draws it for the kept ones), so the two see different noise from the same generator.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import torch

from actors.behaviours.options import RL
from learner.captured import DeviceMetrics, StepGraph
from learner.dqn.learning import double_q_target
from learner.options.targets import k_step_return
from learner.td3.captured import actor_step, critic_step
from service.core import Metrics, TensorBatch

if TYPE_CHECKING:
    from learner.options.learning import OptionsLearner


class CapturedOptions:
    """Runs an `OptionsLearner`'s updates as captured steps."""

    def __init__(self, learner: OptionsLearner, *, compiled: Optional[str] = None) -> None:
        self.learner, self.compiled = learner, compiled
        self.q = learner.options.capture(compiled=compiled)
        self.td3 = learner.rl.capture(compiled=compiled)
        device = learner.rl.device
        self.rl_count = torch.tensor(float(learner.rl.num_updates), device=device)
        """The RL option's updates so far (updates that had any of its rows)."""
        self.metrics = DeviceMetrics(device)
        self.graph = StepGraph(
            self._step,
            device=device,
            metrics=[self.q.metrics, self.td3.metrics, self.metrics],
            sources=[self.td3.noise],
            compiled=compiled,
        )

    def step(self, batch: TensorBatch) -> Metrics:
        self.graph.load("", batch)
        self.graph.run()
        self.learner.num_updates += 1
        return {}

    def _step(self, w: TensorBatch) -> None:
        """Eq. (13) for Q_Ω on the windows that start an option; TD3 (Retrace's eq. 14, or
        TD3's own target with intra-option learning) on the RL option's rows."""
        from learner.options.learning import episode_steps

        learner = self.learner
        valid = episode_steps(w)
        starts = w["option_step"][:, 0] == 0
        returns, discount = k_step_return(w["reward"], w["terminated"], learner.gamma, valid)
        y = double_q_target(
            returns,
            discount,
            w["next_obs"][:, -1],
            online=learner.options.q,
            target=learner.options.target_q,
        )
        any_start = starts.any()
        self.q.fit(
            w["obs"][:, 0],
            w["option"][:, 0],
            y,
            weight=starts.to(y.dtype),
            enabled=any_start,
            names=("losses/option_q", "values/option_q_mean"),
        )
        every = learner.options._target_every
        self.q.move_target(any_start & (torch.remainder(self.q.count, every) == 0))
        rows = (w["option"] == RL) & valid
        self._rl(self._intra(w) if learner.intra_option else self._retrace(w, rows))
        fraction = rows.sum() / valid.sum()
        self.metrics.add("options/rl_fraction_sampled", fraction)

    def _retrace(self, w: TensorBatch, rows: torch.Tensor) -> TensorBatch:
        """The RL option's steps with Q^ret as the critic's target (eq. 14), flattened."""
        target = self.learner.retrace(w)
        v = self.learner.residual_view(w)
        return {
            "obs": v["rl_obs"].flatten(0, 1),
            "action": v["action"].flatten(0, 1),
            "retrace_target": target.flatten(),
            "_rows": rows.flatten().to(target.dtype),
        }

    def _intra(self, w: TensorBatch) -> TensorBatch:
        """Every pair of steps (s_t, c_t, r_t, s_{t+1}) in the windows, flattened, those
        whose next step is the episode's kept (``_rows``)."""
        from learner.options.learning import episode_steps

        v = self.learner.residual_view(w)
        x = v["rl_obs"]
        pairs = episode_steps(w)[:, 1:]
        return {
            "obs": x[:, :-1].flatten(0, 1),
            "next_obs": x[:, 1:].flatten(0, 1),
            "action": v["action"][:, :-1].flatten(0, 1),
            "reward": w["reward"][:, :-1].flatten(),
            "terminated": w["terminated"][:, :-1].flatten(),
            "_rows": pairs.flatten().to(w["reward"].dtype),
        }

    def _rl(self, flat: TensorBatch) -> None:
        """`TD3Learner.update` on the kept rows (``_rows``), gated on the device."""
        rl, td3 = self.learner.rl, self.td3
        enabled = flat["_rows"].sum() > 0
        critic_step(rl, dict(flat, _enabled=enabled), td3.critic_adam, td3.metrics)
        self.rl_count.add_(enabled.to(self.rl_count.dtype))
        delay = enabled & (torch.remainder(self.rl_count, rl._policy_delay) == 0)
        trains = delay & (self.rl_count > rl._frozen_actor_updates)
        actor_step(rl, flat, td3.actor_adam, td3.metrics, count=td3.actor_count, enabled=trains)
        tau = delay.to(torch.float32) * rl._tau
        with torch.no_grad():
            for target, source in ((rl.target_critic, rl.critic), (rl.target_actor, rl.actor)):
                for t, s in zip(target.parameters(), source.parameters(), strict=True):
                    t.lerp_(s, tau)

    def settle(self) -> None:
        """The counters counted on the device, back in the learners (one sync)."""
        learner = self.learner
        counts = torch.stack(
            [c.double() for c in (self.q.count, self.rl_count, self.td3.actor_count)]
        )
        options, rl, actor = (int(c) for c in counts.tolist())
        learner.options.num_updates, learner.rl.num_updates = options, rl
        learner.rl.num_actor_updates = actor

    def read_metrics(self) -> dict[str, float]:
        return {**self.q.read_metrics(), **self.td3.read_metrics(), **self.metrics.read()}
