"""Builds tables from plain configuration data (YAML presets, `graft replay serve --config`).

tables:
  - name: transitions
    max_size: 1000000
    sampler: uniform              # or fifo, lifo, {kind: prioritized, priority_exponent: 0.6, ...}
    remover: fifo                 # or lifo
    rate_limiter: {kind: sample_to_insert_ratio, samples_per_insert: 256, min_size: 1000,
                   error_buffer: 51200}
    max_times_sampled: 0          # 0 = unlimited
    max_sequence_length: 1        # longest window a sample may ask for
    allow_nonfinite: false
    seed: 0                       # the sampler's random generator (default: fresh entropy)
    max_bytes: 2147483648         # optional: fewer items than max_size where these bytes hold fewer
    signature: {obs: {dtype: float32, shape: [3]}, ...}
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any, Optional

from service.memory import MemoryBudget
from service.replay.server.rate_limiters import MinSize, RateLimiter, SampleToInsertRatio
from service.replay.server.samplers import Prioritized, make_sampler
from service.replay.server.signature import Signature
from service.replay.server.table import Table
from service.replay.server.table_memory import MemoryLedger, capped_size, item_bytes, table_bytes

TABLE_KEYS = frozenset(
    {
        "name", "max_size", "signature", "sampler", "remover", "rate_limiter",
        "max_times_sampled", "max_sequence_length", "allow_nonfinite", "seed", "max_bytes",
    }
)  # fmt: skip


def make_rate_limiter(spec: Optional[Mapping[str, Any]]) -> RateLimiter:
    """``{"kind": "min_size", "min_size": N}`` or ``{"kind": "sample_to_insert_ratio", ...}``."""
    spec = dict(spec or {"kind": "min_size", "min_size": 1})
    kind = spec.pop("kind", "min_size")
    if kind == "min_size":
        return MinSize(**spec)
    if kind == "sample_to_insert_ratio":
        return SampleToInsertRatio(**spec)
    raise ValueError(f"unknown rate limiter kind {kind!r}; use min_size or sample_to_insert_ratio")


def make_tables(specs: Iterable[Mapping[str, Any]], *, budget: MemoryBudget) -> list[Table]:
    """Builds the tables, each once its worst-case bytes fit in what the ones before it
    left of `budget`: a table that cannot fit is refused before anything is allocated."""
    ledger = MemoryLedger(budget)
    return [make_table(spec, ledger=ledger) for spec in specs]


def make_table(
    spec: Mapping[str, Any], *, seed: Optional[int] = None, ledger: Optional[MemoryLedger] = None
) -> Table:
    """Builds one table; refuses unknown keys and unworkable settings with the reason.

    The sampler draws from a generator seeded with the spec's ``seed`` (else `seed`,
    else fresh entropy): the same inserts and sample requests in the same order then
    draw the same items. With a `ledger`, the table's worst-case bytes (``max_bytes``
    lowering its capacity) are claimed from its budget first.
    """
    unknown = sorted(set(spec) - TABLE_KEYS)
    if unknown:
        raise ValueError(f"table config has unknown key(s) {unknown}; known: {sorted(TABLE_KEYS)}")
    for required in ("name", "max_size", "signature"):
        if required not in spec:
            raise ValueError(f"table config is missing '{required}'")
    seed = spec.get("seed", seed)
    if seed is not None and not (isinstance(seed, int) and seed >= 0):
        raise ValueError(f"table config seed={seed!r} must be an integer >= 0")
    name, max_size = spec["name"], int(spec["max_size"])
    signature = Signature.from_dict(
        spec["signature"], allow_nonfinite=bool(spec.get("allow_nonfinite", False))
    )
    sampler = make_sampler(spec.get("sampler"))
    remover = spec.get("remover", "fifo")
    max_times_sampled = int(spec.get("max_times_sampled", 0))
    max_sequence_length = int(spec.get("max_sequence_length", 1))
    per_item = item_bytes(
        signature,
        max_times_sampled=max_times_sampled,
        max_sequence_length=max_sequence_length,
        remover=remover,
    )
    if max_size >= 1:  # a size below 1 is refused with its reason by Table
        max_size = capped_size(name, max_size, per_item, spec.get("max_bytes"))
        if ledger is not None:
            need = table_bytes(max_size, per_item, prioritized=isinstance(sampler, Prioritized))
            ledger.claim(name, max_size, per_item, need)
    return Table(
        name,
        max_size=max_size,
        signature=signature,
        sampler=sampler,
        remover=remover,
        rate_limiter=make_rate_limiter(spec.get("rate_limiter")),
        max_times_sampled=max_times_sampled,
        max_sequence_length=max_sequence_length,
        seed=seed,
    )
