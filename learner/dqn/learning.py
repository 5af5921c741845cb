"""Double DQN learning step: the target (eq. 4 with Double Q-learning) and `DQNLearner`."""

from __future__ import annotations

import copy
from typing import Any, Optional

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from learner.device import CPU, VALID, Adam, CompileMode, compile_networks
from learner.dqn.captured import CapturedDQN
from learner.dqn.config import DQNConfig
from learner.dqn.networks import make_q_network
from learner.selection import with_tree_only
from learner.td3.learning import soft_update


@torch.no_grad()
def double_q_target(
    returns: torch.Tensor,
    discount: torch.Tensor,
    next_obs: torch.Tensor,
    *,
    online: nn.Module,
    target: nn.Module,
) -> torch.Tensor:
    """y = R + D · Q_target(s', argmax_a' Q_online(s', a')) (van Hasselt et al. 2016).

    The online network picks the action, the target network values it: eq. (4) without
    the max's overestimation. One-step DQN passes R = r, D = γ(1 − terminated); the
    option learner passes the k-step return of eq. (13), R = Σ_i γ^i r_i, D = γ^k(1 − d).

    Args:
        returns: R, [B].
        discount: D, [B] (zero where the window ended in a terminal state).
        next_obs: s', [B, obs_dim].
        online: Q_θ, [B, obs_dim] -> [B, n].
        target: Q_φ, same shapes.

    Returns:
        y, [B], without gradient.
    """
    best = online(next_obs).argmax(dim=1, keepdim=True)
    return returns + discount * target(next_obs).gather(1, best).squeeze(1)


def mean_over(values: torch.Tensor, weight: Optional[torch.Tensor]) -> torch.Tensor:
    """The mean of `values` [B], or over the rows `weight` [B] (0 or 1) keeps: the batch
    keeps its shape, so compiled networks and CUDA graphs see one shape, and nothing waits
    on the device to count rows."""
    if weight is None:
        return values.mean()
    return (values * weight).sum() / weight.sum()


def large_margin_loss(
    q: torch.Tensor,
    expert_action: torch.Tensor,
    margin: float,
    weight: Optional[torch.Tensor] = None,
) -> torch.Tensor:
    """DQfD's supervised loss (Hester et al. 2018, eq. 2), as a mean over the batch:
    max_a [Q(s, a) + l(a_E, a)] − Q(s, a_E), l = margin where a ≠ a_E, else 0.

    Zero once Q ranks the expert's action a_E above every other by at least `margin`.

    Args:
        q: Q(s, ·), [B, n].
        expert_action: a_E = μ(s), int64 [B].
        margin: l for every action other than a_E.
        weight: the rows that count (`mean_over`); all when None.
    """
    chosen = expert_action.long().unsqueeze(1)
    penalty = torch.full_like(q, margin).scatter(1, chosen, 0.0)
    return mean_over((q + penalty).max(dim=1).values - q.gather(1, chosen).squeeze(1), weight)


def window_returns(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    gamma: float,
    valid: Optional[torch.Tensor] = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """n-step returns to the window's end from every step of windows [B, n].

    R_j = Σ_{i=j}^{m−1} γ^{i−j} r_i and D_j = γ^{m−j} (1 − d_{m−1}), where m is the number of
    the window's steps that are its episode's (`valid`, a prefix; all n without it): step j
    bootstraps from the state after the episode's last step in the window. A window never
    crosses an episode end, so only that step can be terminal. Training every step (not only
    the first) reaches every step of an episode; after an episode's end, replay repeats its
    last step to fill the window, and those steps are no one's (R = 0 there).

    Returns:
        (R, D), both [B, n], for `double_q_target`.
    """
    n = rewards.shape[1]
    if valid is not None:
        rewards = rewards * valid
    returns = torch.empty_like(rewards)
    returns[:, n - 1] = rewards[:, n - 1]
    for j in range(n - 2, -1, -1):
        returns[:, j] = rewards[:, j] + gamma * returns[:, j + 1]
    if valid is None:
        steps_left = torch.arange(n, 0, -1, dtype=rewards.dtype, device=rewards.device)
    else:  # the episode's steps from j to the window's end
        steps_left = valid.to(rewards.dtype).flip(1).cumsum(1).flip(1)
    alive = 1.0 - terminated[:, -1:].to(rewards.dtype)
    return returns, gamma**steps_left * alive


def linear_decay(start: float, end: float, *, step: int, steps: int) -> float:
    """start + (end − start) · min(step / steps, 1): `start` at step 0, `end` from `steps` on."""
    return end if step >= steps else start + (end - start) * step / steps


def margin_weight(update: int, *, burn_in: int, total: int, after_burn_in: bool) -> float:
    """The large-margin loss's weight at update `update` (counted from 0): 1 in the
    burn-in; after it 0, or with `after_burn_in` 1 − (update − burn_in) / (total − burn_in),
    down to 0 at the run's last update."""
    if update < burn_in:
        return 1.0
    if not after_burn_in or update >= total:
        return 0.0
    return linear_decay(1.0, 0.0, step=update - burn_in, steps=total - burn_in)


class DQNLearner:
    """Online and target Q networks, Adam; the target moves every `target_update_every`.

    With `config.warmup` = hardcoded, the first `config.burn_in_updates` updates (drawn from
    the demonstrations alone) add `large_margin_loss` towards the recorded μ(s); with
    `config.margin_after_burn_in` the later ones too, weighted by `margin_weight`.

    With `config.learning_rate_end` set, update u (counted from 0) steps at
    lr(u) = linear_decay(learning_rate, learning_rate_end, step=u, steps=total_updates):
    the rate follows the update count, so a resumed run continues the same schedule.
    """

    def __init__(
        self,
        obs_dim: int,
        num_actions: int,
        *,
        config: DQNConfig,
        seed: int,
        total_updates: Optional[int] = None,
        device: torch.device = CPU,
        compile: CompileMode = "off",
    ) -> None:
        """`total_updates` (the run's update count) is needed iff the rate decays; the
        networks are drawn on the CPU, then live and learn on `device`, their forward
        passes compiled as `compile` says."""
        if config.learning_rate_end is not None and (total_updates is None or total_updates < 0):
            raise ValueError(
                f"learning_rate_end={config.learning_rate_end} decays the rate over the run's "
                f"updates, but total_updates={total_updates}; pass the phase's update count "
                "(>= 0), or set learning_rate_end to None for a constant rate"
            )
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(int(np.random.SeedSequence(seed).generate_state(1)[0]))
            self.q = make_q_network(obs_dim, num_actions, config.hidden_sizes)
        self.device = torch.device(device)
        self.q.to(self.device)
        self.target_q = copy.deepcopy(self.q).requires_grad_(False)
        self.optimizer = Adam(self.q.parameters(), lr=config.learning_rate, device=self.device)
        compile_networks([self.q, self.target_q], compile)
        self._capturing = compile == "captured"
        self._captured: Optional[CapturedDQN] = None
        self._gamma = config.gamma
        self._target_every = config.target_update_every
        self._target_tau = config.target_tau
        self._max_grad_norm = config.max_grad_norm
        self._lr_start, self._lr_end = config.learning_rate, config.learning_rate_end
        self._total_updates = total_updates
        self._margin_updates = config.burn_in_updates if config.warmup == "hardcoded" else 0
        self._margin = config.margin
        self._margin_after = config.margin_after_burn_in and config.warmup == "hardcoded"
        if self._margin_after and total_updates is None:
            raise ValueError("margin_after_burn_in decays over the run: pass total_updates")
        self.num_updates = 0
        self.tree_only = False
        """Set by the final selection (`keep_tree`): the greedy policy is μ alone."""

    def _margin_weight(self) -> float:
        return margin_weight(
            self.num_updates,
            burn_in=self._margin_updates,
            total=self._total_updates or 0,
            after_burn_in=self._margin_after,
        )

    @property
    def learning_rate(self) -> float:
        """The rate the next update steps at."""
        if self._lr_end is None or self._total_updates is None:
            return self._lr_start
        return linear_decay(
            self._lr_start, self._lr_end, step=self.num_updates, steps=self._total_updates
        )

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """One gradient step on the Huber loss against the Double DQN target.

        Args:
            batch: ``obs`` [B, obs_dim], ``action`` [B] int64, ``reward`` [B],
                ``terminated`` [B] bool, ``next_obs`` [B, obs_dim]; or windows of n
                steps, every column [B, n, ...], for n-step returns, with ``_valid``
                [B, n] (replay's: which steps are the episode's; all without it). In the
                burn-in with warmup: hardcoded, also ``backbone_action`` (μ(s), int64) of
                the same shape as ``action``.
        """
        if self.captures:
            return self._captured_step(batch)
        batch = {k: v.to(self.device, non_blocking=True) for k, v in batch.items()}
        obs, action, y, expert, weight = self.fit_inputs(batch, expert=self._with_margin())
        return self.fit(obs, action, y, expert_action=expert, weight=weight)

    @property
    def captures(self) -> bool:
        """Updates run as captured steps (`learner.dqn.captured`)."""
        return self._capturing or self._captured is not None

    def capture(self, *, compiled: Optional[str] = None) -> CapturedDQN:
        """The captured update, made at its first use; `compiled` (on the CPU) compiles
        each step whole with that ``torch.compile`` backend."""
        if self._captured is None or self._captured.compiled != compiled:
            self._captured = CapturedDQN(self, compiled=compiled)
        return self._captured

    def _captured_step(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        return (self._captured or self.capture()).step(batch)

    def read_metrics(self) -> dict[str, float]:
        """The captured updates' metrics since the last read, averaged (none when eager)."""
        return {} if self._captured is None else self._captured.read_metrics()

    def _with_margin(self) -> bool:
        """The next update adds the large-margin loss (it reads ``backbone_action``)."""
        return self._margin > 0.0 and self._margin_weight() > 0.0

    def fit_inputs(
        self, batch: dict[str, torch.Tensor], *, expert: bool
    ) -> tuple[
        torch.Tensor, torch.Tensor, torch.Tensor, Optional[torch.Tensor], Optional[torch.Tensor]
    ]:
        """(obs, action, y, expert action or None, row weight or None) of `fit` for a batch
        of transitions or of windows (`update` has its columns)."""
        expert_action = batch["backbone_action"] if expert else None
        if batch["reward"].dim() == 1:
            # Truncation is not termination: only a terminal s' stops the bootstrap.
            discount = self._gamma * (1.0 - batch["terminated"].float())
            y = double_q_target(
                batch["reward"], discount, batch["next_obs"], online=self.q, target=self.target_q
            )
            return batch["obs"], batch["action"], y, expert_action, None
        valid = batch.get(VALID)
        returns, discounts = window_returns(
            batch["reward"], batch["terminated"], self._gamma, valid
        )
        b, n = returns.shape
        bootstrap = double_q_target(
            torch.zeros(b, device=self.device),
            torch.ones(b, device=self.device),
            batch["next_obs"][:, -1],
            online=self.q,
            target=self.target_q,
        )
        y = returns + discounts * bootstrap.unsqueeze(1)
        return (
            batch["obs"].flatten(0, 1),
            batch["action"].flatten(),
            y.flatten(),
            None if expert_action is None else expert_action.flatten(),
            # The episode's steps only: padding after its end repeats its last step.
            None if valid is None else valid.flatten().to(y.dtype),
        )

    def fit(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        y: torch.Tensor,
        *,
        expert_action: Optional[torch.Tensor] = None,
        weight: Optional[torch.Tensor] = None,
    ) -> dict[str, float]:
        """One Huber-loss step of Q(obs, action) towards a target y (plus the large-margin
        loss towards `expert_action` when given), over the rows `weight` keeps (all when
        None); counts an update."""
        loss, q, margin_loss = self.loss(
            obs, action, y, expert_action, weight, margin_weight=self._margin_weight()
        )
        scalars = [loss.detach(), mean_over(q.detach(), weight)]
        if margin_loss is not None:
            scalars.append(margin_loss.detach())
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(self.q.parameters(), self._max_grad_norm)
        lr = self.learning_rate
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        self.optimizer.step()
        self.num_updates += 1
        if self.num_updates % self._target_every == 0:
            soft_update(self.target_q, self.q, self._target_tau)
        # One host transfer for all metrics (a single sync on an accelerator).
        values = torch.stack(scalars).tolist()
        metrics = {"losses/q": values[0], "values/q_mean": values[1], "charts/learning_rate": lr}
        if margin_loss is not None:
            metrics["losses/margin"] = values[2]
        return metrics

    def loss(
        self,
        obs: torch.Tensor,
        action: torch.Tensor,
        y: torch.Tensor,
        expert_action: Optional[torch.Tensor],
        weight: Optional[torch.Tensor],
        *,
        margin_weight: float | torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, Optional[torch.Tensor]]:
        """(the loss `fit` descends, Q(obs, action), the large-margin loss or None)."""
        q_all = self.q(obs)
        q = q_all.gather(1, action.long().unsqueeze(1)).squeeze(1)
        if weight is None:
            loss = F.smooth_l1_loss(q, y)
        else:
            loss = mean_over(F.smooth_l1_loss(q, y, reduction="none"), weight)
        margin_loss = None
        if expert_action is not None:
            margin_loss = large_margin_loss(q_all, expert_action, self._margin, weight)
            loss = loss + margin_weight * margin_loss
        return loss, q, margin_loss

    def policy_state(self) -> dict[str, torch.Tensor]:
        """The Q network's weights as detached CPU copies, for broadcasting to actors, and
        the tree-only flag."""
        if self._captured is not None:
            return with_tree_only(self._captured.policy_state(), self.tree_only)
        weights = {k: v.detach().to("cpu", copy=True) for k, v in self.q.state_dict().items()}
        return with_tree_only(weights, self.tree_only)

    def tree_state(self) -> dict[str, torch.Tensor]:
        """Published weights under which the greedy policy is μ alone."""
        return with_tree_only(self.policy_state(), True)

    def keep_tree(self) -> None:
        """From now on the greedy policy (published and checkpointed) is μ alone."""
        self.tree_only = True

    def state_dict(self) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "target_q": self.target_q.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "num_updates": self.num_updates,
            "tree_only": self.tree_only,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.target_q.load_state_dict(state["target_q"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.num_updates = int(state["num_updates"])
        self.tree_only = bool(state.get("tree_only", False))
        if self._captured is not None:  # its graphs hold the old optimiser state
            self._captured = CapturedDQN(self, compiled=self._captured.compiled)
