"""TD3's behaviour: the broadcast deterministic actor plus Gaussian noise (sec. II-B2).

Warm-up is uniform random over the action box, or, when a hard-coded policy μ is given,
μ(s) + N(0, σ²) (the demonstrations of sec. III-A); with μ given every step also records
``backbone_action`` = μ(s), the target of the imitation losses (eq. 8, TD3+BC).
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from actors.hardcoded import HardCodedPolicy
from actors.policies import GaussianExploration, UniformRandomPolicy
from actors.policy_net import ActingNet
from service.core import Columns, ColumnSpec, WeightArrays


def box_column(shape: tuple[int, ...]) -> ColumnSpec:
    """Signature entry of a float32 action-shaped column."""
    return {"dtype": "float32", "shape": list(shape)}


class GaussianBehaviour:
    """a ~ N(π(s), σ²), unclipped; the environment clips."""

    def __init__(
        self,
        network: ActingNet,
        *,
        std: float,
        low: np.ndarray,
        high: np.ndarray,
        hardcoded: Optional[HardCodedPolicy] = None,
        warmup_std: float = 0.0,
    ) -> None:
        """Initialises the behaviour.

        Args:
            network: The acting network π (weights arrive by `load`).
            std: Absolute exploration noise std, in action units.
            low: Lower action bounds [A].
            high: Upper action bounds [A].
            hardcoded: μ; when given, warm-up acts μ(s) + N(0, warmup_std²) and every
                step records ``backbone_action`` = μ(s).
            warmup_std: Std of the demonstration noise around μ(s), in action units.

        Raises:
            ValueError: If `hardcoded` is given with a non-positive `warmup_std`.
        """
        if hardcoded is not None and not warmup_std > 0.0:
            raise ValueError(
                f"warmup_std={warmup_std} must be > 0 around a hard-coded policy: its "
                "deterministic actions have no density, so log_prob would be undefined"
            )
        self.network = network
        self.exploration = GaussianExploration(std, low, high)
        self.uniform = UniformRandomPolicy(low, high)
        self.hardcoded = hardcoded
        self.demo = GaussianExploration(warmup_std, low, high) if hardcoded else None
        self.action_shape = tuple(np.shape(low))

    def columns(self) -> dict[str, ColumnSpec]:
        cols = {"action": box_column(self.action_shape)}
        if self.hardcoded is not None:
            cols["backbone_action"] = box_column(self.action_shape)
        return {**cols, "log_prob": {"dtype": "float32", "shape": []}}

    def load(self, weights: WeightArrays) -> None:
        self.network.load(weights)

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        return self.network(obs)

    def act(
        self,
        obs: np.ndarray,
        rng: np.random.Generator,
        *,
        warmup: bool,
        envs: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, Columns]:
        extra: Columns = {}
        if self.hardcoded is not None:
            mu = np.asarray(self.hardcoded(obs), dtype=np.float32)
            extra["backbone_action"] = mu
        if warmup and self.demo is not None:
            action, log_prob = self.demo.sample(extra["backbone_action"], rng)
        elif warmup:
            action, log_prob = self.uniform.sample(len(obs), rng)
        else:
            action, log_prob = self.exploration.sample(self.greedy(obs), rng)
        columns = {"action": action, **extra, "log_prob": log_prob.astype(np.float32)}
        return self.exploration.clip(action), columns

    def next_columns(self, next_obs: np.ndarray, envs: Optional[np.ndarray] = None) -> Columns:
        return {}  # nothing about s'

    def end_episodes(self, ended: np.ndarray, envs: Optional[np.ndarray] = None) -> None:
        pass  # memoryless

    def stats(self) -> dict[str, float]:
        return {}
