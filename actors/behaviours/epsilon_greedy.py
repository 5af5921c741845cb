"""ε-greedy over a Q network (DQN, sec. II-B1): greedy with probability 1 − ε, else uniform.

Warm-up is uniform (ε = 1), or, when a hard-coded policy μ is given, ε-greedy around μ(s)
(demonstrations); with μ given every step also records ``backbone_action`` = μ(s), the
action the large-margin loss ranks first.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from actors.behaviours.switching import check_margin, split_weights, switch_mask
from actors.hardcoded import HardCodedPolicy
from actors.policy_net import ActingNet
from service.core import Columns, ColumnSpec, WeightArrays


def linear_epsilon(step: int, *, start: float, end: float, decay_steps: int) -> float:
    """ε decayed linearly from `start` to `end` over `decay_steps`, then held at `end`."""
    frac = min(step / max(decay_steps, 1), 1.0)
    return start + frac * (end - start)


def epsilon_greedy(
    q_values: np.ndarray, epsilon: float, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Samples ε-greedy actions and their log-likelihoods.

    P(a) = 1 − ε + ε/n for the greedy action and ε/n for every other one.

    Args:
        q_values: Q(s, ·), [B, n].
        epsilon: Exploration probability in [0, 1].
        rng: The only source of randomness.

    Returns:
        ``(action, log_prob)``: int64 [B] and float32 [B].
    """
    batch, n = q_values.shape
    greedy = q_values.argmax(axis=1)
    explore = rng.random(batch) < epsilon
    action = np.where(explore, rng.integers(0, n, size=batch), greedy).astype(np.int64)
    prob = np.where(action == greedy, 1.0 - epsilon + epsilon / n, epsilon / n)
    return action, np.log(prob).astype(np.float32)


class EpsilonGreedyBehaviour:
    """ε-greedy actions of the broadcast Q network; ε follows a linear schedule.

    The schedule counts this actor's steps times `num_actors`, an estimate of the run's
    global env steps that needs no round trip to the learner.
    """

    def __init__(
        self,
        q_network: ActingNet,
        *,
        epsilon_start: float,
        epsilon_end: float,
        decay_env_steps: int,
        num_actors: int,
        hardcoded: Optional[HardCodedPolicy] = None,
        demo_epsilon: float = 0.1,
        switch_margin: Optional[float] = None,
    ) -> None:
        """Initialises the behaviour.

        Args:
            q_network: Maps [B, obs_dim] to Q values [B, n].
            epsilon_start: ε at the first policy step.
            epsilon_end: ε after `decay_env_steps` global env steps.
            decay_env_steps: Length of the linear decay, in the run's env steps.
            num_actors: Actors sharing the run (scales this actor's step count).
            hardcoded: μ, discrete actions [B] from observations; when given, warm-up
                acts ε-greedy around μ(s) with `demo_epsilon` and every step records
                ``backbone_action`` = μ(s).
            demo_epsilon: Probability of a uniform action instead of μ(s) in warm-up.
            switch_margin: With `hardcoded`, the greedy policy acts argmax_a Q(s, a) only
                where Q values it above μ(s) by this fraction of |Q(s, μ(s))|
                (`switch_mask`), else μ(s). None: plain argmax. Exploration ignores it.

        Raises:
            ValueError: If `hardcoded` is given with `demo_epsilon` outside (0, 1].
        """
        if hardcoded is not None and not 0.0 < demo_epsilon <= 1.0:
            raise ValueError(
                f"demo_epsilon={demo_epsilon} must lie in (0, 1] around a hard-coded policy: "
                "its deterministic actions alone would give other actions probability 0"
            )
        check_margin("switch_margin", switch_margin)
        if switch_margin is not None and hardcoded is None:
            raise ValueError("switch_margin compares with μ's action: it needs a hard-coded policy")
        self.hardcoded, self.demo_epsilon = hardcoded, demo_epsilon
        self.switch_margin = switch_margin
        self.tree_only = False
        self._switched: list[float] = []
        self.q_network = q_network
        self.start, self.end, self.decay = epsilon_start, epsilon_end, decay_env_steps
        self.num_actors = num_actors
        self.steps = 0
        self._epsilons: list[float] = []

    @property
    def epsilon(self) -> float:
        return linear_epsilon(
            self.steps * self.num_actors, start=self.start, end=self.end, decay_steps=self.decay
        )

    def columns(self) -> dict[str, ColumnSpec]:
        columns: dict[str, ColumnSpec] = {"action": {"dtype": "int64", "shape": []}}
        if self.hardcoded is not None:
            columns["backbone_action"] = {"dtype": "int64", "shape": []}
        return {**columns, "log_prob": {"dtype": "float32", "shape": []}}

    def load(self, weights: WeightArrays) -> None:
        policy, _, self.tree_only = split_weights(weights)
        self.q_network.load(policy)

    def _q(self, obs: np.ndarray) -> np.ndarray:
        return self.q_network(obs)

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        if self.hardcoded is None or (self.switch_margin is None and not self.tree_only):
            return self._q(obs).argmax(axis=1)
        mu = np.asarray(self.hardcoded(obs), dtype=np.int64).reshape(len(obs))
        if self.tree_only:  # the final selection kept the tree
            return mu
        q = self._q(obs)
        best = q.argmax(axis=1)
        rows = np.arange(len(obs))
        assert self.switch_margin is not None
        use = switch_mask(q[rows, mu], q[rows, best], self.switch_margin)
        self._switched.append(float(use.mean()))
        return np.where(use, best, mu)

    def act(
        self,
        obs: np.ndarray,
        rng: np.random.Generator,
        *,
        warmup: bool,
        envs: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, Columns]:
        self.steps += len(obs)
        extra: Columns = {}
        q = self._q(obs)
        if self.hardcoded is not None:
            mu = np.asarray(self.hardcoded(obs), dtype=np.int64).reshape(len(obs))
            extra["backbone_action"] = mu
        if warmup and self.hardcoded is not None:
            # ε-greedy around μ(s): μ's one-hot as the "Q values" to be greedy on.
            epsilon, q = self.demo_epsilon, np.eye(q.shape[1], dtype=np.float32)[mu]
        else:
            epsilon = 1.0 if warmup else self.epsilon
        self._epsilons.append(epsilon)
        action, log_prob = epsilon_greedy(q, epsilon, rng)
        return action, {"action": action, **extra, "log_prob": log_prob}

    def next_columns(self, next_obs: np.ndarray, envs: Optional[np.ndarray] = None) -> Columns:
        return {}  # nothing about s'

    def end_episodes(self, ended: np.ndarray, envs: Optional[np.ndarray] = None) -> None:
        pass  # memoryless

    def stats(self) -> dict[str, float]:
        out = {"charts/epsilon": float(np.mean(self._epsilons))} if self._epsilons else {}
        if self._switched:  # greedy steps Q's action was taken (with switching)
            out["switch/policy_share"] = float(np.mean(self._switched))
        self._epsilons.clear()
        self._switched.clear()
        return out
