"""The checks a table's configuration passes before any storage is allocated: each refusal
names the table, the value and the deadlock or waste it would cause."""

from __future__ import annotations

from service.replay.server.rate_limiters import RateLimiter, SampleToInsertRatio
from service.replay.server.samplers import Fifo, Lifo, Sampler

REMOVERS = ("fifo", "lifo")


def check_configuration(
    where: str,
    *,
    max_size: int,
    sampler: Sampler,
    remover: str,
    rate_limiter: RateLimiter,
    max_times_sampled: int,
    max_sequence_length: int,
) -> None:
    """Refuses a configuration a table cannot serve.

    Raises:
        ValueError: naming `where` (the table), the value and what is allowed.
    """
    if max_size < 1:
        raise ValueError(f"{where}: max_size must be >= 1, got {max_size}")
    if remover not in REMOVERS:
        raise ValueError(f"{where}: remover {remover!r} is not one of {REMOVERS}")
    if max_times_sampled < 0:
        raise ValueError(f"{where}: max_times_sampled must be >= 0 (0 = unlimited)")
    if not 1 <= max_sequence_length <= max_size:
        raise ValueError(f"{where}: max_sequence_length must lie in [1, max_size]")
    if rate_limiter.min_size > max_size:
        raise ValueError(
            f"{where}: rate limiter min_size {rate_limiter.min_size} exceeds "
            f"max_size {max_size}, so sampling could never start"
        )
    if max_sequence_length > 1 and isinstance(sampler, (Fifo, Lifo)):
        raise ValueError(
            f"{where}: a {sampler.name} sampler always picks the same items, so it "
            "cannot redraw a window that is still incomplete; use uniform or prioritized"
        )
    if (
        max_times_sampled
        and isinstance(rate_limiter, SampleToInsertRatio)
        and rate_limiter.samples_per_insert > max_times_sampled
    ):
        raise ValueError(
            f"{where}: samples_per_insert {rate_limiter.samples_per_insert} exceeds "
            f"max_times_sampled {max_times_sampled}: items would be used up faster "
            "than the ratio lets inserts replace them, and sampling would deadlock"
        )
