"""Table signatures: the dtype and per-item shape of every column a table stores."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.replay.codec import ALLOWED_DTYPES, Batch


class SignatureError(ValueError):
    """A batch does not match the table's signature; the message names the column."""


@dataclass(frozen=True)
class ColumnSpec:
    """One column: numpy dtype string (e.g. '<f4') and the shape of a single item."""

    dtype: str
    shape: tuple[int, ...] = ()

    @property
    def item_bytes(self) -> int:
        return int(np.dtype(self.dtype).itemsize * np.prod(self.shape, dtype=np.int64))


@dataclass(frozen=True)
class Signature:
    """Maps column name to ColumnSpec; every insert is validated against it."""

    columns: Mapping[str, ColumnSpec]
    allow_nonfinite: bool = False

    def __post_init__(self) -> None:
        if not self.columns:
            raise ValueError("a signature needs at least one column")
        for name, spec in self.columns.items():
            if not name or name.startswith("_"):
                raise ValueError(f"column name {name!r} is empty or reserved (starts with '_')")
            dtype = np.dtype(spec.dtype).str
            if dtype not in ALLOWED_DTYPES:
                raise ValueError(f"column '{name}' has unsupported dtype {spec.dtype!r}")

    @classmethod
    def from_dict(
        cls, columns: Mapping[str, Mapping[str, Any]], *, allow_nonfinite: bool = False
    ) -> Signature:
        """Builds a signature from ``{name: {"dtype": "float32", "shape": [3]}}``."""
        return cls(
            {
                name: ColumnSpec(np.dtype(spec["dtype"]).str, tuple(spec.get("shape", ())))
                for name, spec in columns.items()
            },
            allow_nonfinite=allow_nonfinite,
        )

    def to_json(self) -> str:
        return json.dumps(
            {name: {"dtype": s.dtype, "shape": list(s.shape)} for name, s in self.columns.items()}
        )

    @property
    def item_bytes(self) -> int:
        return sum(spec.item_bytes for spec in self.columns.values())

    def validate(self, batch: Batch, *, extra: frozenset[str] = frozenset()) -> int:
        """Checks names, dtypes, shapes and finiteness; returns the number of items.

        Args:
            batch: decoded columns.
            extra: reserved column names the caller accepts besides the signature.

        Raises:
            SignatureError: naming the first offending column and what was expected.
        """
        unknown = sorted(set(batch) - set(self.columns) - extra)
        if unknown:
            raise SignatureError(f"unknown column(s) {unknown}; table has {sorted(self.columns)}")
        missing = sorted(set(self.columns) - set(batch))
        if missing:
            raise SignatureError(f"missing column(s) {missing}")
        sizes = {name: int(array.shape[0]) for name, array in batch.items()}
        if len(set(sizes.values())) != 1:
            raise SignatureError(f"columns disagree on the number of items: {sizes}")
        n = next(iter(sizes.values()))
        for name, spec in self.columns.items():
            array = batch[name]
            if array.dtype.str != spec.dtype:
                raise SignatureError(
                    f"column '{name}' has dtype {array.dtype.str}, table expects {spec.dtype}"
                )
            if array.shape[1:] != spec.shape:
                raise SignatureError(
                    f"column '{name}' has shape {array.shape}, table expects {(n, *spec.shape)}"
                )
            if (
                not self.allow_nonfinite
                and array.dtype.kind == "f"
                and not np.isfinite(array).all()
            ):
                raise SignatureError(f"column '{name}' contains NaN or Inf")
        return n
