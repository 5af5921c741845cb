"""Where a stored item's columns lie in its record: a table keeps each item's columns side
by side in one row of bytes, and each column is a strided view of those rows."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from service.replay.server.signature import Signature


@dataclass(frozen=True)
class Field:
    """Where one column lies in a stored item's record (bytes `offset` to `offset + nbytes`)."""

    offset: int
    nbytes: int
    dtype: np.dtype[Any]
    shape: tuple[int, ...]

    def of(self, records: np.ndarray) -> np.ndarray:
        """This column of `records` (uint8, one row per item): a strided view."""
        if self.nbytes == 0:
            return np.zeros((len(records), *self.shape), self.dtype)
        window = records[:, self.offset : self.offset + self.nbytes]
        return window.view(self.dtype).reshape(len(records), *self.shape)


def record_layout(signature: Signature) -> tuple[dict[str, Field], int]:
    """Each column's place in an item's record, and the record's length: widest elements
    first and records padded to 8 bytes, so every field sits on its own alignment."""
    fields, offset = {}, 0
    by_width = sorted(signature.columns.items(), key=lambda c: -np.dtype(c[1].dtype).itemsize)
    for name, spec in by_width:
        fields[name] = Field(offset, spec.item_bytes, np.dtype(spec.dtype), spec.shape)
        offset += spec.item_bytes
    return {name: fields[name] for name in signature.columns}, -(-offset // 8) * 8
