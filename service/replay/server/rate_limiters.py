"""Rate limiters: decide when a table admits inserts and samples (after Reverb's design).

A limiter only answers "may this call go ahead now?"; the table blocks the caller
(with a timeout) until it may. A call admitted while the ratio is inside its error
buffer may overshoot the buffer by its own batch, so batch sizes never deadlock.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MinSize:
    """Samples wait until the table holds `min_size` items; inserts never wait."""

    min_size: int = 1

    def __post_init__(self) -> None:
        if self.min_size < 1:
            raise ValueError(f"min_size must be >= 1, got {self.min_size}")

    def insert_allowed(self, *, inserts: int, samples: int) -> bool:
        return True

    def sample_allowed(self, *, size: int, inserts: int, samples: int) -> bool:
        return size >= self.min_size

    def describe(self) -> str:
        return f"MinSize(min_size={self.min_size})"


@dataclass(frozen=True)
class SampleToInsertRatio:
    """Holds samples per insert near `samples_per_insert` once `min_size` items arrived.

    The imbalance ``inserts * samples_per_insert - samples`` is kept within
    ``min_size * samples_per_insert ± error_buffer``: inserts wait when actors run
    ahead of the learner, samples wait when the learner runs ahead of the actors.
    ``sample_credit`` extra samples are allowed once `min_size` items arrived (a learner
    burn-in on the first data); inserts wait until the learner has spent them.
    """

    samples_per_insert: float
    min_size: int = 1
    error_buffer: float = 1.0
    sample_credit: float = 0.0

    def __post_init__(self) -> None:
        if self.samples_per_insert <= 0:
            raise ValueError(f"samples_per_insert must be > 0, got {self.samples_per_insert}")
        if self.min_size < 1:
            raise ValueError(f"min_size must be >= 1, got {self.min_size}")
        if self.sample_credit < 0:
            raise ValueError(f"sample_credit must be >= 0, got {self.sample_credit}")
        if self.error_buffer < self.samples_per_insert:
            raise ValueError(
                f"error_buffer ({self.error_buffer}) is smaller than samples_per_insert "
                f"({self.samples_per_insert}): one insert would already leave the buffer, so "
                "inserts and samples would lock-step one item at a time; use an error_buffer "
                "of at least samples_per_insert (Reverb's rule), better a few batches' worth"
            )

    def _imbalance(self, inserts: int, samples: int) -> float:
        at_min_size = self.min_size * self.samples_per_insert
        return inserts * self.samples_per_insert - samples - at_min_size + self.sample_credit

    def insert_allowed(self, *, inserts: int, samples: int) -> bool:
        return inserts < self.min_size or self._imbalance(inserts, samples) <= self.error_buffer

    def sample_allowed(self, *, size: int, inserts: int, samples: int) -> bool:
        return size >= self.min_size and self._imbalance(inserts, samples) >= -self.error_buffer

    def describe(self) -> str:
        return (
            f"SampleToInsertRatio(samples_per_insert={self.samples_per_insert}, "
            f"min_size={self.min_size}, error_buffer={self.error_buffer}, "
            f"sample_credit={self.sample_credit})"
        )


RateLimiter = MinSize | SampleToInsertRatio
