"""Builds tables from plain configuration data (YAML presets, CLI files)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from service.rate_limiters import MinSize, RateLimiter, SampleToInsertRatio
from service.signature import Signature
from service.table import Table


def make_rate_limiter(spec: Mapping[str, Any] | None) -> RateLimiter:
    """``{"kind": "min_size", "min_size": N}`` or ``{"kind": "sample_to_insert_ratio", ...}``."""
    spec = dict(spec or {"kind": "min_size", "min_size": 1})
    kind = spec.pop("kind", "min_size")
    if kind == "min_size":
        return MinSize(**spec)
    if kind == "sample_to_insert_ratio":
        return SampleToInsertRatio(**spec)
    raise ValueError(f"unknown rate limiter kind {kind!r}; use min_size or sample_to_insert_ratio")


def make_table(spec: Mapping[str, Any], *, seed: int | None = None) -> Table:
    """Builds one table from ``{"name", "max_size", "signature", "rate_limiter"?}``."""
    known = {"name", "max_size", "signature", "rate_limiter", "allow_nonfinite"}
    unknown = sorted(set(spec) - known)
    if unknown:
        raise ValueError(f"table config has unknown key(s) {unknown}; known: {sorted(known)}")
    return Table(
        spec["name"],
        max_size=int(spec["max_size"]),
        signature=Signature.from_dict(
            spec["signature"], allow_nonfinite=bool(spec.get("allow_nonfinite", False))
        ),
        rate_limiter=make_rate_limiter(spec.get("rate_limiter")),
        seed=seed,
    )
