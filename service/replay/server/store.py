"""The replay service's pure-Python core: named tables, exactly-once inserts, durability.

The gRPC servicer (service/replay/server/servicer.py) only decodes, calls this, and encodes.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable
from contextlib import ExitStack
from pathlib import Path
from typing import Optional

from service.replay.codec import Batch, decode_batch
from service.replay.server import durability
from service.replay.server.table import Table

log = logging.getLogger(__name__)


class UnknownTable(KeyError):
    """A request named a table the server does not have."""

    def __str__(self) -> str:
        return str(self.args[0])


class ReplayCore:
    """Holds the tables and, per writer, the highest batch sequence number stored.

    With a `checkpoint_dir`, every acknowledged insert is logged before it is
    acknowledged and the state is restored from that folder on construction.
    """

    def __init__(
        self,
        tables: Iterable[Table],
        *,
        checkpoint_dir: Optional[Path] = None,
        fsync: bool = False,
    ) -> None:
        self.tables: dict[str, Table] = {}
        for table in tables:
            if table.name in self.tables:
                raise ValueError(f"two tables are named '{table.name}'")
            self.tables[table.name] = table
        if not self.tables:
            raise ValueError("a replay server needs at least one table")
        self.acked: dict[str, int] = {}
        self._acked_lock = threading.Lock()  # also orders log appends
        self._checkpoint_lock = threading.Lock()
        self.started = time.monotonic()
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir else None
        self._wal: Optional[durability.WriteAheadLog] = None
        if self.checkpoint_dir is not None:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
            segment = self._restore()
            self._wal = durability.WriteAheadLog(self.checkpoint_dir, segment, fsync=fsync)

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
        timeout: Optional[float] = None,
        payload: bytes = b"",
    ) -> Optional[int]:
        """Stores a batch; returns items stored, or None if it is a duplicate resend.

        A writer numbers its batches 1, 2, 3, ...; the server remembers the highest
        number stored per writer, so a batch resent after a lost acknowledgement is
        dropped instead of stored twice. `payload` (the encoded batch) is what the
        write-ahead log records.
        """
        target = self.table(table)
        if writer_id:
            with self._acked_lock:
                if sequence <= self.acked.get(writer_id, 0):
                    return None

        def on_stored() -> None:  # runs under the table lock, in the table's insert order
            with self._acked_lock:
                if self._wal is not None:
                    self._wal.append(table, writer_id, sequence, payload)
                if writer_id:
                    self.acked[writer_id] = max(sequence, self.acked.get(writer_id, 0))

        return target.insert(batch, timeout=timeout, writer=writer_id, on_stored=on_stored)

    def checkpoint(self) -> Optional[Path]:
        """Snapshots all tables consistently, then writes them without blocking samples."""
        if self.checkpoint_dir is None or self._wal is None:
            return None
        with self._checkpoint_lock:
            with ExitStack() as stack:
                for name in sorted(self.tables):
                    stack.enter_context(self.tables[name].lock)
                stack.enter_context(self._acked_lock)
                snapshots = {name: t.snapshot() for name, t in self.tables.items()}
                acked = dict(self.acked)
                segment = self._wal.rotate()
            # Locks released: inserts and samples go on while the file is written.
            path = durability.write_checkpoint(self.checkpoint_dir, snapshots, acked, segment)
            durability.prune(self.checkpoint_dir, segment)
        log.info("checkpoint written to %s", path)
        return path

    def _restore(self) -> int:
        """Loads the newest checkpoint and replays the log after it; returns the next segment."""
        assert self.checkpoint_dir is not None
        found = durability.read_latest_checkpoint(self.checkpoint_dir)
        first_segment = 0
        if found is not None:
            states, acked, first_segment = found
            for name, state in states.items():
                if name in self.tables:
                    self.tables[name].restore(state)
                else:
                    log.warning("checkpoint has table '%s', which is not configured", name)
            self.acked = acked
        replayed = 0
        last_segment = first_segment
        for path in durability.segments(self.checkpoint_dir, first_segment):
            last_segment = int(path.stem.split("-")[1])
            for table, writer, sequence, payload in durability.read_segment(path):
                if table not in self.tables:
                    continue
                target = self.tables[table]
                if writer and sequence <= self.acked.get(writer, 0):
                    continue
                target.insert(decode_batch(payload), writer=writer, rate_limited=False)
                if writer:
                    self.acked[writer] = sequence
                replayed += 1
        if found is not None or replayed:
            log.info("restored from %s (+%d logged batches)", self.checkpoint_dir, replayed)
        return last_segment + 1

    def close(self) -> None:
        if self._wal is not None:
            self._wal.close()
