"""A replay table: fixed-size columnar storage with a sampler, a remover and a rate limiter.

Storage is preallocated numpy columns, so a table's memory is known up front and a
sample is one fancy-index per column. Items are keyed by their insertion number.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from service.codec import Batch
from service.rate_limiters import MinSize, RateLimiter
from service.signature import Signature


class RateLimitTimeout(TimeoutError):
    """The rate limiter did not admit the call before its timeout."""


@dataclass
class TableStats:
    """Counters a table reports through Info and metrics."""

    inserts: int = 0
    samples: int = 0
    insert_blocked_s: float = 0.0
    sample_blocked_s: float = 0.0


class Table:
    """One named table. FIFO eviction at `max_size`, uniform sampling.

    Thread-safe: inserts and samples come from many gRPC worker threads.
    """

    def __init__(
        self,
        name: str,
        *,
        max_size: int,
        signature: Signature,
        rate_limiter: RateLimiter | None = None,
        seed: int | None = None,
    ) -> None:
        if max_size < 1:
            raise ValueError(f"table '{name}': max_size must be >= 1, got {max_size}")
        self.rate_limiter = rate_limiter or MinSize(1)
        if self.rate_limiter.min_size > max_size:
            raise ValueError(
                f"table '{name}': rate limiter min_size {self.rate_limiter.min_size} exceeds "
                f"max_size {max_size}, so sampling could never start"
            )
        self.name = name
        self.max_size = max_size
        self.signature = signature
        self.stats = TableStats()
        self._columns = {
            column: np.zeros((max_size, *spec.shape), dtype=spec.dtype)
            for column, spec in signature.columns.items()
        }
        self._keys = np.zeros(max_size, dtype=np.uint64)
        self._size = 0
        self._rng = np.random.default_rng(seed)
        self._cond = threading.Condition()

    @property
    def size(self) -> int:
        return self._size

    @property
    def bytes_in_memory(self) -> int:
        return sum(c.nbytes for c in self._columns.values()) + self._keys.nbytes

    def _wait(self, admitted, timeout: float | None, what: str) -> float:
        """Blocks (holding no lock while asleep) until `admitted()`; returns seconds waited."""
        if admitted():
            return 0.0
        start = time.monotonic()
        deadline = None if timeout is None else start + timeout
        while not admitted():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                raise RateLimitTimeout(
                    f"table '{self.name}': {what} not admitted by "
                    f"{self.rate_limiter.describe()} within {timeout:.3g} s"
                )
            self._cond.wait(remaining if remaining is None else min(remaining, 1.0))
        return time.monotonic() - start

    def insert(self, batch: Batch, *, timeout: float | None = None) -> int:
        """Stores a validated batch, evicting the oldest items; returns items stored."""
        n = self.signature.validate(batch)
        if n == 0:
            return 0
        with self._cond:
            s = self.stats
            s.insert_blocked_s += self._wait(
                lambda: self.rate_limiter.insert_allowed(inserts=s.inserts, samples=s.samples),
                timeout,
                "insert",
            )
            keep = min(n, self.max_size)  # a batch larger than the table keeps its newest rows
            keys = np.arange(s.inserts + n - keep, s.inserts + n, dtype=np.uint64)
            slots = keys % self.max_size
            for column, array in self._columns.items():
                array[slots] = batch[column][n - keep :]
            self._keys[slots] = keys
            s.inserts += n
            self._size = min(self._size + n, self.max_size)
            self._cond.notify_all()
        return n

    def sample(self, batch_size: int, *, timeout: float | None = None) -> Batch:
        """Draws `batch_size` items uniformly (with replacement) plus their key,
        sampling probability and importance weight."""
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        with self._cond:
            s = self.stats
            s.sample_blocked_s += self._wait(
                lambda: self.rate_limiter.sample_allowed(
                    size=self._size, inserts=s.inserts, samples=s.samples
                ),
                timeout,
                "sample",
            )
            slots = self._rng.integers(0, self._size, size=batch_size)
            out = {column: array[slots] for column, array in self._columns.items()}
            out["_key"] = self._keys[slots]
            s.samples += batch_size
            size = self._size
            self._cond.notify_all()
        out["_probability"] = np.full(batch_size, 1.0 / size)
        out["_weight"] = np.ones(batch_size, dtype=np.float32)
        return out
