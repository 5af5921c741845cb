"""An insert batch checked against its table's signature and reserved columns, before
any lock is taken, so the table stores it without further checks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from service.replay.codec import Batch
from service.replay.server.signature import Signature, SignatureError

RESERVED_INSERT_COLUMNS = frozenset({"_priority", "_stream"})


@dataclass(frozen=True)
class PreparedInsert:
    """A batch checked against the table's signature, ready to `store`."""

    batch: Batch
    n: int
    priority: Optional[np.ndarray]
    stream: np.ndarray


def prepare_insert(
    batch: Batch, signature: Signature, *, table: str, by_priority: bool
) -> PreparedInsert:
    """Validates `batch` against `signature` and the reserved columns: `_priority` (only
    for a `table` that samples `by_priority`) and `_stream` (episode ids, default 0)."""
    n = signature.validate(batch, extra=RESERVED_INSERT_COLUMNS)
    priority = batch.get("_priority")
    if priority is not None:
        if priority.shape != (n,) or priority.dtype.kind != "f":
            raise SignatureError(f"column '_priority' must be float with shape ({n},)")
        if not np.all(np.isfinite(priority) & (priority >= 0)):
            raise SignatureError("column '_priority' must be finite and >= 0")
        if not by_priority:
            raise SignatureError(f"table '{table}' does not sample by priority")
    stream = batch.get("_stream")
    if stream is None:
        return PreparedInsert(batch, n, priority, np.zeros(n, dtype=np.int64))
    if stream.shape != (n,) or stream.dtype.kind not in "iu":
        raise SignatureError(f"column '_stream' must be integer with shape ({n},)")
    return PreparedInsert(batch, n, priority, stream.astype(np.int64))
