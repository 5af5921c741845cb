"""The replay service's pure-Python core: named tables, exactly-once inserts, durability.

The gRPC servicer (service/replay/server/servicer.py) only decodes, calls this, and encodes.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Optional

from service.replay.codec import decode_batch
from service.replay.server import durability
from service.replay.server.folder_lock import lock_folder
from service.replay.server.table import LockBusy, PreparedInsert, Table
from service.replay.server.writers import DEFAULT_MAX_WRITERS, Writers

log = logging.getLogger(__name__)


class UnknownTable(KeyError):
    """A request named a table the server does not have."""

    def __str__(self) -> str:
        return str(self.args[0])


class CallEnded(TimeoutError):
    """The call was cancelled or passed its deadline before its batches could be stored."""


@dataclass(frozen=True)
class StagedInsert:
    """One batch of an Insert stream, validated and waiting for the stream to end."""

    table: str
    prepared: PreparedInsert
    writer: str = ""
    sequence: int = 0
    payload: bytes = b""
    """The encoded batch, as the write-ahead log records it."""


class ReplayCore:
    """Holds the tables and, per writer, the highest batch sequence number stored.

    With a `checkpoint_dir` (locked: one server per folder), every insert is logged
    before it is stored and acknowledged, and the state is restored from that folder
    on construction.
    """

    def __init__(
        self,
        tables: Iterable[Table],
        *,
        checkpoint_dir: Optional[Path] = None,
        fsync: bool = False,
        max_writers: int = DEFAULT_MAX_WRITERS,
    ) -> None:
        self.tables: dict[str, Table] = {}
        for table in tables:
            if table.name in self.tables:
                raise ValueError(f"two tables are named '{table.name}'")
            self.tables[table.name] = table
        if not self.tables:
            raise ValueError("a replay server needs at least one table")
        self.writers = Writers(max_writers)
        self.fsync = fsync
        self._acked_lock = threading.Lock()  # orders log appends, stores and acks
        self._checkpoint_lock = threading.Lock()
        self.started = time.monotonic()
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir else None
        self._wal: Optional[durability.WriteAheadLog] = None
        self._folder_lock: Optional[IO[str]] = None
        if self.checkpoint_dir is not None:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
            self._folder_lock = lock_folder(self.checkpoint_dir)
            segment = self._restore()
            self._wal = durability.WriteAheadLog(self.checkpoint_dir, segment, fsync=fsync)

    def table(self, name: str) -> Table:
        try:
            return self.tables[name]
        except KeyError:
            raise UnknownTable(
                f"no table named '{name}'; tables are {sorted(self.tables)}"
            ) from None

    def commit(
        self,
        staged: Sequence[StagedInsert],
        *,
        alive: Callable[[], bool] = lambda: True,
        blocked_s: float = 0.0,
        blocking: bool = True,
    ) -> Optional[tuple[int, int]]:
        """Stores the batches of one Insert stream all together, or none of them.

        Batches already stored (resends: a sequence at or below its writer's high-water
        mark) are dropped first, under the same locks as the store, so a batch raced by
        two calls is stored once. The rest are stored only if every table's rate limiter
        admits an insert now and the call is still `alive()`; each is logged before it
        is stored. `blocked_s` (time already waited) goes into the tables' stats.

        Returns:
            (items stored, batches dropped as resends), or None while a rate limiter
            says wait (nothing was stored; try again after a change).

        Raises:
            CallEnded: `alive()` was false when the batches could have been stored.
            LockBusy: `blocking` is False and a lock is held (nothing was stored).
        """
        targets = {s.table: self.table(s.table) for s in staged}
        with ExitStack() as stack:
            locks: list[threading.Condition | threading.Lock] = [
                *(targets[name].lock for name in sorted(targets)),
                self._acked_lock,
            ]
            for lock in locks:
                if not lock.acquire(blocking=blocking):
                    raise LockBusy("a table or the writer map")
                stack.callback(lock.release)
            fresh: list[StagedInsert] = []
            high: dict[str, int] = {}
            for s in staged:
                if s.writer:
                    if s.sequence <= max(self.writers.acked(s.writer), high.get(s.writer, 0)):
                        continue
                    high[s.writer] = s.sequence
                fresh.append(s)
            dropped = len(staged) - len(fresh)
            used = {s.table for s in fresh}
            if not all(targets[name].insert_admitted() for name in used):
                return None
            if fresh and not alive():
                raise CallEnded(
                    "the call was cancelled or passed its deadline before the rate "
                    "limiter admitted it; nothing was stored"
                )
            if self._wal is not None:
                for s in fresh:
                    self._wal.append(s.table, s.writer, s.sequence, s.payload)
            stored = sum(targets[s.table].store(s.prepared, writer=s.writer) for s in fresh)
            for writer, sequence in high.items():
                self.writers.ack(writer, sequence)
            for name in used:
                targets[name].stats.insert_blocked_s += blocked_s
        return stored, dropped

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
                acked = self.writers.snapshot()
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
            self.writers.restore(acked)
        replayed = 0
        last_segment = first_segment
        for path in durability.segments(self.checkpoint_dir, first_segment):
            last_segment = int(path.stem.split("-")[1])
            for table, writer, sequence, payload in durability.read_segment(path):
                if table not in self.tables:
                    continue
                target = self.tables[table]
                if writer and sequence <= self.writers.acked(writer):
                    continue
                target.insert(decode_batch(payload), writer=writer, rate_limited=False)
                if writer:
                    self.writers.ack(writer, sequence)
                replayed += 1
        if found is not None or replayed:
            log.info("restored from %s (+%d logged batches)", self.checkpoint_dir, replayed)
        return last_segment + 1

    def close(self) -> None:
        if self._wal is not None:
            self._wal.close()
        if self._folder_lock is not None:
            self._folder_lock.close()  # releases the folder
