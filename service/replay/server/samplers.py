"""Samplers: which stored items a sample draws, and with what probability.

A sampler picks rows from a table's slots; the table gathers the data. Samplers check
their own arguments and say why a setting is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.replay.server.slots import FreeListSlots, RingSlots

Slots = RingSlots | FreeListSlots


class Uniform:
    """Every stored item equally likely (with replacement)."""

    name = "uniform"

    def sample(
        self, slots: Slots, rng: np.random.Generator, n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        return slots.uniform(rng, n), np.full(n, 1.0 / slots.size)

    def describe(self) -> str:
        return "Uniform()"


class Fifo:
    """The oldest items, in insertion order (a queue when paired with max_times_sampled=1)."""

    name = "fifo"

    def sample(
        self, slots: Slots, rng: np.random.Generator, n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        return slots.oldest(n), np.ones(n)

    def describe(self) -> str:
        return "Fifo()"


class Lifo:
    """The newest items first."""

    name = "lifo"

    def sample(
        self, slots: Slots, rng: np.random.Generator, n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        return slots.newest(n), np.ones(n)

    def describe(self) -> str:
        return "Lifo()"


@dataclass
class Prioritized:
    """P(i) = p_i^α / Σ_j p_j^α (Schaul et al. 2016), over a sum-tree of rows.

    New items without an explicit `_priority` get the largest priority seen so far,
    so every item is sampled at least once with a fair chance.
    """

    priority_exponent: float = 0.6
    importance_exponent: float = 0.4
    name = "prioritized"

    def __post_init__(self) -> None:
        if not 0.0 <= self.priority_exponent <= 1.0:
            raise ValueError(
                f"priority_exponent α={self.priority_exponent} must lie in [0, 1] "
                "(0 is uniform, 1 fully proportional)"
            )
        if not 0.0 <= self.importance_exponent <= 1.0:
            raise ValueError(
                f"importance_exponent β={self.importance_exponent} must lie in [0, 1] "
                "(1 fully corrects the sampling bias)"
            )
        self._tree = np.zeros(2, dtype=np.float64)
        self._leaves = 1
        self.max_priority = 1.0

    def bind(self, capacity: int) -> None:
        """Sizes the sum-tree for a table of `capacity` rows."""
        self._leaves = 1 << max(0, math.ceil(math.log2(capacity)))
        self._tree = np.zeros(2 * self._leaves, dtype=np.float64)

    @property
    def total(self) -> float:
        return float(self._tree[1])

    def set(self, rows: np.ndarray, priorities: np.ndarray) -> None:
        """Sets raw priorities (0 for removed rows) and refreshes the sums above them."""
        if len(rows) == 0:
            return
        self.max_priority = max(self.max_priority, float(np.max(priorities, initial=0.0)))
        nodes = rows + self._leaves
        self._tree[nodes] = np.power(priorities, self.priority_exponent)
        nodes = np.unique(nodes // 2)
        while nodes[0] >= 1:
            self._tree[nodes] = self._tree[2 * nodes] + self._tree[2 * nodes + 1]
            if nodes[0] == 1:
                break
            nodes = np.unique(nodes // 2)

    def priorities(self, rows: np.ndarray) -> np.ndarray:
        """Raw priorities p_i of rows (inverts the exponent)."""
        mass: np.ndarray = self._tree[rows + self._leaves]
        if self.priority_exponent == 0:
            return np.where(mass > 0, 1.0, 0.0)
        raw: np.ndarray = np.power(mass, 1.0 / self.priority_exponent)
        return raw

    def sample(
        self, slots: Slots, rng: np.random.Generator, n: int
    ) -> tuple[np.ndarray, np.ndarray]:
        total = self.total
        if total <= 0:
            return slots.uniform(rng, n), np.full(n, 1.0 / slots.size)
        target = rng.uniform(0.0, total, size=n)
        nodes = np.ones(n, dtype=np.int64)
        while nodes[0] < self._leaves:  # descend: all nodes sit on the same level
            left = self._tree[2 * nodes]
            go_right = target >= left
            target = np.where(go_right, target - left, target)
            nodes = 2 * nodes + go_right
        rows = nodes - self._leaves
        mass: np.ndarray = self._tree[nodes]
        # Float round-off can land on a zero-mass leaf at the very end: redraw those uniformly.
        if not np.all(mass > 0):
            bad = mass <= 0
            rows[bad] = slots.uniform(rng, int(bad.sum()))
            mass = self._tree[rows + self._leaves]
        probabilities: np.ndarray = mass / total
        return rows, probabilities

    def importance_weights(self, probabilities: np.ndarray, size: int) -> np.ndarray:
        """w_i = (N·P(i))^-β, normalised by the batch maximum (Schaul et al. 2016)."""
        weights: np.ndarray = np.power(size * probabilities, -self.importance_exponent)
        normalised: np.ndarray = (weights / weights.max()).astype(np.float32)
        return normalised

    def describe(self) -> str:
        return (
            f"Prioritized(priority_exponent={self.priority_exponent}, "
            f"importance_exponent={self.importance_exponent})"
        )


Sampler = Uniform | Fifo | Lifo | Prioritized


def make_sampler(spec: dict[str, Any] | str | None) -> Sampler:
    """``"uniform"``, ``"fifo"``, ``"lifo"`` or ``{"kind": "prioritized", ...}``."""
    spec = {"kind": spec} if isinstance(spec, str) else dict(spec or {"kind": "uniform"})
    kind = spec.pop("kind", "uniform")
    simple: dict[str, type[Uniform | Fifo | Lifo]] = {
        "uniform": Uniform,
        "fifo": Fifo,
        "lifo": Lifo,
    }
    if kind in simple:
        if spec:
            raise ValueError(f"sampler '{kind}' takes no options, got {sorted(spec)}")
        return simple[kind]()
    if kind == "prioritized":
        return Prioritized(**spec)
    raise ValueError(f"unknown sampler {kind!r}; use uniform, fifo, lifo or prioritized")
