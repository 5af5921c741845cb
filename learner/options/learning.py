"""The hierarchical learner: Double DQN on eq. (13) for Q_Ω, TD3 with Retrace (eq. 14) for
the RL option. Every batch is windows [B, k] of consecutive steps of one episode.

V(s_{t+1}) in eq. (14) comes from the option-value network, as the paper specifies:
max_o Q_Ω(s_{t+1}, o) where the option ends after step t, Q_Ω(s_{t+1}, o_t) otherwise.
The traces are cut (c = 0) where the next step starts a new option or belongs to the
hard-coded option: there a' was not drawn from π.

With a residual RL option (actors/behaviours/options.py) the RL learner is TD3 on the
correction c = a − μ(s), its actor and critics seeing [s, μ(s) / scale]: the windows are
rewritten once (`residual_view`) and the rest reads as for the paper's RL option.

With intra-option learning (Sutton, Precup & Singh 1999) the RL option's critic learns
from every step of every window, whichever option acted: an action-value Q(s, a) of the
RL option's own policy can be learnt off-policy from any transition, and a tree step is
the residual option's correction c = 0. Its target is TD3's one-step target (eq. 5), the
value of following the RL option, in place of eq. (14).
"""

from __future__ import annotations

from typing import Any, Optional

import torch

from actors.behaviours.options import RL
from learner.backbone.networks import backbone_input
from learner.device import VALID
from learner.dqn.learning import DQNLearner, double_q_target
from learner.options.captured import CapturedOptions
from learner.options.targets import importance_ratio, k_step_return, retrace_targets, retrace_traces
from learner.td3.learning import TD3Learner


class RetraceTD3Learner(TD3Learner):
    """TD3 whose critic target is given with the batch (``retrace_target``, eq. 14)."""

    def _critic_target(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        return batch["retrace_target"]


def episode_steps(windows: dict[str, torch.Tensor]) -> torch.Tensor:
    """Which steps of windows [B, k] are their episode's: replay's `VALID` (after an
    episode's end it repeats the last step), or every step of windows without it (made by
    hand, or from an older server)."""
    valid = windows.get(VALID)
    return torch.ones_like(windows["reward"], dtype=torch.bool) if valid is None else valid


class OptionsLearner:
    """Q_Ω by Double DQN over k-step option windows; the RL option by TD3 + Retrace."""

    def __init__(
        self,
        options: DQNLearner,
        rl: TD3Learner,
        *,
        option_length: int,
        retrace_lambda: float,
        behaviour_std: float,
        gamma: float,
        residual_scale: Optional[torch.Tensor] = None,
        intra_option: bool = False,
    ) -> None:
        """Combines the two learners.

        Args:
            options: Q_Ω(s, ·) as a Double DQN learner whose "actions" are the two options.
            rl: The RL option's TD3 learner.
            option_length: k, steps per option and per window.
            retrace_lambda: λ of the traces.
            behaviour_std: Std of the actors' Gaussian around π(s), for ρ.
            gamma: Discount of eqs. (13) and (14).
            residual_scale: The action box's half-width when the RL option is residual
                (its learner then sees [s, μ(s) / scale] and the correction); None for
                the paper's RL option.
            intra_option: Train the RL option on every step with TD3's own target (`rl`
                is then a plain `TD3Learner`), not on its own steps with Retrace.
        """
        self.options, self.rl = options, rl
        self.residual_scale = None if residual_scale is None else residual_scale.to(rl.device)
        self.intra_option = intra_option
        self.k, self.lam, self.std, self.gamma = option_length, retrace_lambda, behaviour_std, gamma
        self.num_updates = 0
        self._captured: Optional[CapturedOptions] = None

    def capture(self, *, compiled: Optional[str] = None) -> CapturedOptions:
        """The captured update (`learner.options.captured`), made at its first use."""
        if self._captured is None or self._captured.compiled != compiled:
            self._captured = CapturedOptions(self, compiled=compiled)
        return self._captured

    @property
    def captures(self) -> bool:
        """Updates run as captured steps (as the RL option's learner's do)."""
        return self.rl.captures

    def read_metrics(self) -> dict[str, float]:
        """The captured updates' metrics since the last read, averaged (none when eager)."""
        return {} if self._captured is None else self._captured.read_metrics()

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        """One step of each learner on a batch of windows [B, k, ...] (and ``_valid``
        [B, k], which steps are the episode's: replay repeats an episode's last step after
        its end to fill a window)."""
        if self.rl.captures:
            return self.capture().step(batch)
        device = self.rl.device  # both learners live on it
        batch = {k: v.to(device, non_blocking=True) for k, v in batch.items()}
        self.num_updates += 1
        metrics: dict[str, float] = {}
        valid = episode_steps(batch)
        starts = batch["option_step"][:, 0] == 0
        if starts.any():
            metrics.update(self._update_options({c: v[starts] for c, v in batch.items()}))
        rl_rows = (batch["option"] == RL) & valid
        if self.intra_option:
            metrics.update(self._update_rl_intra(batch))
        elif rl_rows.any():
            metrics.update(self._update_rl(batch, rl_rows))
        metrics["options/rl_fraction_sampled"] = float(rl_rows.sum() / valid.sum())
        return metrics

    def _update_options(self, w: dict[str, torch.Tensor]) -> dict[str, float]:
        """Eq. (13) with Double Q-learning, on windows that start an option."""
        returns, discount = k_step_return(
            w["reward"], w["terminated"], self.gamma, episode_steps(w)
        )
        y = double_q_target(
            returns,
            discount,
            w["next_obs"][:, -1],
            online=self.options.q,
            target=self.options.target_q,
        )
        out = self.options.fit(w["obs"][:, 0], w["option"][:, 0], y)
        return {"losses/option_q": out["losses/q"], "values/option_q_mean": out["values/q_mean"]}

    def residual_view(self, w: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The windows as the residual RL learner sees them: ``rl_obs`` [s, μ(s)/scale] and
        ``action`` the unclipped sampled correction a − μ(s); unchanged without residual."""
        if self.residual_scale is None:
            return dict(w, rl_obs=w["obs"])
        mu = w["hardcoded_action"]
        return dict(
            w,
            rl_obs=backbone_input(w["obs"], mu, self.residual_scale),
            action=w["action"] - mu,
        )

    @torch.no_grad()
    def retrace(self, w: dict[str, torch.Tensor]) -> torch.Tensor:
        """Q^ret for every step of every window, [B, k] (eq. 14)."""
        rl, k = self.rl, self.k
        w = self.residual_view(w)
        obs, next_obs, option = w["rl_obs"], w["next_obs"], w["option"]
        action = torch.clamp(w["action"], rl.actor.action_low, rl.actor.action_high)
        discounts = self.gamma * (1.0 - w["terminated"].float())
        # V(s_{t+1}) from the option-value target network.
        q_next = self.options.target_q(next_obs)  # [B, k, 2]
        option_ends = w["option_step"] == k - 1
        continuing = q_next.gather(-1, option.unsqueeze(-1)).squeeze(-1)
        next_values = torch.where(option_ends, q_next.max(dim=-1).values, continuing)
        # Q(s_{t+1}, a_{t+1}) from the TD3 target critic, on the stored (clipped) action.
        q1, q2 = rl.target_critic(obs[:, 1:], action[:, 1:])
        next_q = torch.cat([torch.min(q1, q2), torch.zeros_like(q1[:, :1])], dim=1)
        # ρ on the UNCLIPPED sampled action, π a Gaussian around the current actor.
        ratio = importance_ratio(w["action"], rl.actor(obs), self.std, w["log_prob"])
        # A trace runs on inside one RL option and stops at the episode's last step.
        same_option = (option == RL) & (w["option_step"] != 0) & episode_steps(w)
        traces = torch.where(same_option, retrace_traces(ratio, self.lam), 0.0)
        next_traces = torch.cat([traces[:, 1:], torch.zeros_like(traces[:, :1])], dim=1)
        return retrace_targets(w["reward"], discounts, next_values, next_q, next_traces)

    def _update_rl(self, w: dict[str, torch.Tensor], rows: torch.Tensor) -> dict[str, float]:
        """TD3 on the RL option's steps, its critic regressed onto Q^ret."""
        target = self.retrace(w)
        w = self.residual_view(w)
        flat = {
            "obs": w["rl_obs"][rows],
            "action": w["action"][rows],
            "retrace_target": target[rows],
        }
        return self.rl.update(flat)

    def _update_rl_intra(self, w: dict[str, torch.Tensor]) -> dict[str, float]:
        """TD3 on every transition (s_t, c_t, r_t, s_{t+1}) inside the windows.

        s_{t+1} is the next step's row (with μ(s_{t+1}) when residual), so each window
        gives the steps whose next step is its episode's too: none of them is terminal.
        """
        v = self.residual_view(w)
        x = v["rl_obs"]
        pairs = episode_steps(w)[:, 1:]  # step t's successor is the episode's
        flat = {
            "obs": x[:, :-1][pairs],
            "next_obs": x[:, 1:][pairs],
            "action": v["action"][:, :-1][pairs],
            "reward": w["reward"][:, :-1][pairs],
            "terminated": w["terminated"][:, :-1][pairs],
        }
        return self.rl.update(flat)

    def policy_state(self) -> dict[str, torch.Tensor]:
        """Both acting networks, prefixed; `OptionsBehaviour.load` splits them."""
        options = {f"options.{k}": v for k, v in self.options.policy_state().items()}
        actor = {f"actor.{k}": v for k, v in self.rl.policy_state().items()}
        return {**options, **actor}

    def state_dict(self) -> dict[str, Any]:
        if self._captured is not None:
            self._captured.settle()
        return {
            "options": self.options.state_dict(),
            "rl": self.rl.state_dict(),
            "num_updates": self.num_updates,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.options.load_state_dict(state["options"])
        self.rl.load_state_dict(state["rl"])
        self.num_updates = int(state["num_updates"])
        if self._captured is not None:  # its graphs hold the old optimiser state
            self._captured = None
            self.capture()
