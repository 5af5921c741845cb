"""The hierarchical behaviour (sec. III-C): a policy over options picks, every k steps,
the hard-coded option or the RL option, which then acts for k steps.

The policy over options is ε-greedy on Q_Ω(s, ·) (option 0 hard-coded, 1 RL). The RL
option acts a ~ N(π(s), σ²), unclipped, with its log-likelihood recorded for the Retrace
ratios of eq. (14); the hard-coded option acts μ(s) deterministically (its steps train
no RL critic, so it records log_prob 0). Each environment keeps its own option clock,
restarted when its episode ends.

Two changes from the options literature are optional. A *residual* RL option acts
μ(s) + c with c ~ N(π([s, μ(s)]), σ²) and c ∈ [−L, L] (residual policy learning, Silver
et al. 2018): with π zero at the start it is the hard-coded option plus noise, never worse
to pick; replay records μ(s) (``hardcoded_action``) so the learner can recover c. A
*switching margin* m picks the RL option only where Q_Ω(s, RL) > Q_Ω(s, hard-coded) + m,
so noise in two close option values does not hand control to the RL option.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from actors.behaviours.backbone import backbone_input
from actors.behaviours.epsilon_greedy import epsilon_greedy, linear_epsilon
from actors.behaviours.gaussian import box_column
from actors.hardcoded import HardCodedPolicy
from actors.policies import GaussianExploration, UniformRandomPolicy
from actors.policy_net import ActingNet
from service.core import Columns, ColumnSpec, WeightArrays

HARDCODED, RL = 0, 1
"""Option indices: the column `option` and the outputs of Q_Ω."""


def split_weights(weights: WeightArrays) -> tuple[WeightArrays, WeightArrays]:
    """Splits broadcast weights into (Q_Ω, RL actor) state dicts by their prefixes."""
    options = {
        k.removeprefix("options."): v for k, v in weights.items() if k.startswith("options.")
    }
    actor = {k.removeprefix("actor."): v for k, v in weights.items() if k.startswith("actor.")}
    return options, actor


class OptionsBehaviour:
    """ε-greedy over {hard-coded, RL} every `option_length` steps; the option then acts."""

    def __init__(
        self,
        option_q: ActingNet,
        actor: ActingNet,
        hardcoded: HardCodedPolicy,
        *,
        option_length: int,
        std: float,
        low: np.ndarray,
        high: np.ndarray,
        epsilon_start: float,
        epsilon_end: float,
        decay_env_steps: int,
        num_actors: int,
        residual_limit: Optional[float] = None,
        switch_margin: float = 0.0,
    ) -> None:
        """`residual_limit` L makes the RL option residual (None: it acts π(s) alone);
        `switch_margin` is m of the option choice."""
        self.option_q, self.actor = option_q, actor
        self.hardcoded = hardcoded
        self.residual_limit, self.margin = residual_limit, switch_margin
        self._scale = np.abs(np.asarray(high, dtype=np.float32))
        if residual_limit is not None:
            bound = np.full(np.shape(low), residual_limit, dtype=np.float32)
            self.uniform_correction = UniformRandomPolicy(-bound, bound)
        self.k = option_length
        self.exploration = GaussianExploration(std, low, high)
        self.uniform = UniformRandomPolicy(low, high)
        self.action_shape = tuple(np.shape(low))
        self.eps = (epsilon_start, epsilon_end, decay_env_steps)
        self.num_actors = num_actors
        self.steps = 0
        self._option = np.zeros(0, np.int64)
        self._clock = np.zeros(0, np.int64)  # step within the running option, 0..k-1
        self._greedy_option = np.zeros(0, np.int64)
        self._greedy_clock = np.zeros(0, np.int64)
        self._used: list[np.ndarray] = []

    def columns(self) -> dict[str, ColumnSpec]:
        columns: dict[str, ColumnSpec] = {
            "action": box_column(self.action_shape),
            "log_prob": {"dtype": "float32", "shape": []},
            "option": {"dtype": "int64", "shape": []},
            "option_step": {"dtype": "int64", "shape": []},
        }
        if self.residual_limit is not None:
            columns["hardcoded_action"] = box_column(self.action_shape)
        return columns

    def load(self, weights: WeightArrays) -> None:
        options, actor = split_weights(weights)
        self.option_q.load(options)
        self.actor.load(actor)
        # An evaluation starts fresh options, chosen by the new Q_Ω.
        self._greedy_option = np.zeros(0, np.int64)
        self._greedy_clock = np.zeros(0, np.int64)

    @property
    def epsilon(self) -> float:
        start, end, decay = self.eps
        return linear_epsilon(self.steps * self.num_actors, start=start, end=end, decay_steps=decay)

    def _correction(self, obs: np.ndarray, mu: np.ndarray) -> np.ndarray:
        """π([s, μ(s) / scale]): the residual RL option's mean correction."""
        return self.actor(backbone_input(obs, mu, self._scale))

    def _choose(
        self,
        obs: np.ndarray,
        option: np.ndarray,
        clock: np.ndarray,
        epsilon: float,
        rng: Optional[np.random.Generator],
    ) -> tuple[np.ndarray, np.ndarray]:
        """Re-chooses the option where the clock is at 0 (fresh option or new episode)."""
        if len(option) != len(obs) or len(clock) != len(obs):
            option, clock = np.zeros(len(obs), np.int64), np.zeros(len(obs), np.int64)
        due = clock == 0
        if due.any():
            q = self.option_q(obs[due])
            q[:, RL] -= self.margin  # the RL option must beat the hard-coded one by m
            if rng is None:
                option[due] = q.argmax(axis=1)
            else:
                option[due] = epsilon_greedy(q, epsilon, rng)[0]
        return option, clock

    def _rows(self, envs: Optional[np.ndarray], n: int) -> np.ndarray:
        """The environments of n rows; the per-environment option state grown to hold
        them (a new environment starts with its clock at 0: a fresh option)."""
        rows = np.arange(n) if envs is None else np.asarray(envs, dtype=np.int64)
        size = int(rows.max()) + 1 if len(rows) else 0
        if len(self._option) < size:
            grow = size - len(self._option)
            self._option = np.concatenate([self._option, np.zeros(grow, np.int64)])
            self._clock = np.concatenate([self._clock, np.zeros(grow, np.int64)])
        return rows

    def act(
        self,
        obs: np.ndarray,
        rng: np.random.Generator,
        *,
        warmup: bool,
        envs: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, Columns]:
        epsilon = 1.0 if warmup else self.epsilon
        rows = self._rows(envs, len(obs))
        option, clock = self._choose(obs, self._option[rows], self._clock[rows], epsilon, rng)
        self.steps += len(obs)
        mu = np.asarray(self.hardcoded(obs), dtype=np.float32)
        if self.residual_limit is not None:
            # The warm-up spreads corrections over all of [−L, L] (the critic then knows
            # them all); after it, c ~ N(π, σ²) around the learnt correction.
            limit = self.residual_limit
            if warmup:
                correction, rl_log_prob = self.uniform_correction.sample(len(obs), rng)
            else:
                correction, rl_log_prob = self.exploration.sample(self._correction(obs, mu), rng)
            rl_action = mu + np.clip(correction, -limit, limit)
        elif warmup:
            rl_action, rl_log_prob = self.uniform.sample(len(obs), rng)
        else:
            rl_action, rl_log_prob = self.exploration.sample(self.actor(obs), rng)
        use_rl = option == RL
        action = np.where(use_rl[:, None], rl_action, mu).astype(np.float32)
        log_prob = np.where(use_rl, rl_log_prob, 0.0).astype(np.float32)
        columns: Columns = {
            "action": action,
            "log_prob": log_prob,
            "option": option.copy(),
            "option_step": clock.copy(),
        }
        if self.residual_limit is not None:
            columns["hardcoded_action"] = mu
            # The learner recovers the unclipped sampled correction as action − μ(s).
            columns["action"] = np.where(use_rl[:, None], mu + correction, mu).astype(np.float32)
        if not warmup:
            self._used.append(use_rl)
        self._option[rows], self._clock[rows] = option, (clock + 1) % self.k
        return self.exploration.clip(action), columns

    def next_columns(self, next_obs: np.ndarray, envs: Optional[np.ndarray] = None) -> Columns:
        return {}  # nothing about s'

    def end_episodes(self, ended: np.ndarray, envs: Optional[np.ndarray] = None) -> None:
        rows = self._rows(envs, len(ended))
        self._clock[rows[ended]] = 0  # a new episode starts a new option

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """Greedy options, each held k calls; a change of batch size restarts the clocks."""
        option, clock = self._choose(obs, self._greedy_option, self._greedy_clock, 0.0, None)
        use_rl = option == RL
        mu = np.asarray(self.hardcoded(obs), dtype=np.float32)
        if self.residual_limit is not None:
            rl_action = mu + self._correction(obs, mu)
        else:
            rl_action = self.actor(obs)
        action = np.where(use_rl[:, None], rl_action, mu)
        self._used.append(use_rl)
        self._greedy_option, self._greedy_clock = option, (clock + 1) % self.k
        return self.exploration.clip(action)

    def stats(self) -> dict[str, float]:
        if not self._used:
            return {}
        out = {"options/rl_fraction": float(np.concatenate(self._used).mean())}
        if self.steps:
            out["options/epsilon"] = self.epsilon
        self._used.clear()
        return out
