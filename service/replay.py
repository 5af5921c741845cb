"""The replay service's pure-Python core: named tables plus exactly-once bookkeeping.

The gRPC servicer (service/server.py) only decodes, calls this, and encodes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable

from service.codec import Batch
from service.table import Table


class UnknownTable(KeyError):
    """A request named a table the server does not have."""

    def __str__(self) -> str:
        return str(self.args[0])


class ReplayCore:
    """Holds the tables and, per writer, the highest batch sequence number stored."""

    def __init__(self, tables: Iterable[Table]) -> None:
        self.tables: dict[str, Table] = {}
        for table in tables:
            if table.name in self.tables:
                raise ValueError(f"two tables are named '{table.name}'")
            self.tables[table.name] = table
        if not self.tables:
            raise ValueError("a replay server needs at least one table")
        self.acked: dict[str, int] = {}
        self._acked_lock = threading.Lock()
        self.started = time.monotonic()

    def table(self, name: str) -> Table:
        try:
            return self.tables[name]
        except KeyError:
            raise UnknownTable(
                f"no table named '{name}'; tables are {sorted(self.tables)}"
            ) from None

    def insert(
        self,
        table: str,
        batch: Batch,
        *,
        writer_id: str = "",
        sequence: int = 0,
        timeout: float | None = None,
    ) -> int | None:
        """Stores a batch; returns items stored, or None if it is a duplicate resend.

        A writer numbers its batches 1, 2, 3, ...; the server remembers the highest
        number stored per writer, so a batch resent after a lost acknowledgement is
        dropped instead of stored twice.
        """
        target = self.table(table)
        if writer_id:
            # Serialise per-writer bookkeeping; a writer sends its batches in order.
            with self._acked_lock:
                if sequence <= self.acked.get(writer_id, 0):
                    return None
            stored = target.insert(batch, timeout=timeout)
            with self._acked_lock:
                self.acked[writer_id] = max(sequence, self.acked.get(writer_id, 0))
            return stored
        return target.insert(batch, timeout=timeout)
