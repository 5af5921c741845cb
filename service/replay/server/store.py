"""The replay service's pure-Python core: named tables, exactly-once inserts, durability.

The gRPC servicer (service/replay/server/servicer.py) only decodes, calls this, and encodes.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Optional

from service.memory import MemoryBudget
from service.replay.codec import decode_batch
from service.replay.server import durability
from service.replay.server.durability import StorageError
from service.replay.server.folder_lock import lock_folder
from service.replay.server.prepared_insert import PreparedInsert
from service.replay.server.table import LockBusy, Table
from service.replay.server.writers import DEFAULT_MAX_WRITERS, Writers

log = logging.getLogger(__name__)


class UnknownTable(KeyError):
    """A request named a table the server does not have."""

    def __str__(self) -> str:
        return str(self.args[0])


class FolderUnusable(ValueError):
    """The checkpoint folder cannot be restored for these tables (another table config, a
    broken way back, an unreadable manifest); nothing in it was changed."""


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


@dataclass
class DurabilityStats:
    """What the durable state went through; the metrics export these."""

    checkpoints: int = 0
    checkpoint_failures: int = 0
    log_append_failures: int = 0
    damaged_log_records: int = 0
    """Log records skipped at start-up: their checksum failed, or their batch did not decode."""
    damaged_checkpoints: int = 0
    """Checkpoints found unreadable at start-up (set aside as `*.damaged`)."""
    unlogged_samples: int = 0
    """Items sampled while the log could not record it (a restart would not count them)."""


class ReplayCore:
    """Holds the tables and, per writer, the highest batch sequence number stored.

    With a `checkpoint_dir` (locked: one server per folder), every insert is logged
    before it is stored and acknowledged, and the state is restored from that folder
    on construction.

    Raises:
        FolderUnusable: the folder holds data of another table config, or data that
            cannot be restored whole (the message says what and how to proceed).
        FolderInUse: another live server holds the folder.
    """

    def __init__(
        self,
        tables: Iterable[Table],
        *,
        checkpoint_dir: Optional[Path] = None,
        fsync: bool = False,
        max_writers: int = DEFAULT_MAX_WRITERS,
        memory_budget: Optional[MemoryBudget] = None,
    ) -> None:
        self.tables: dict[str, Table] = {}
        self.memory_budget = memory_budget
        """What the tables were checked against (`table_config.make_tables`), if anything."""
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
        self.durability = DurabilityStats()
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir else None
        self._wal: Optional[durability.WriteAheadLog] = None
        self._folder_lock: Optional[IO[str]] = None
        if self.checkpoint_dir is not None:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
            # Locked first: the temporary files and the log are ours alone from here on.
            self._folder_lock = lock_folder(self.checkpoint_dir)
            try:
                self._open(self.checkpoint_dir, fsync)
            except BaseException:
                self._folder_lock.close()
                raise

    def _open(self, folder: Path, fsync: bool) -> None:
        """Cleans, checks and restores the (locked) folder, then starts the log."""
        for path in durability.remove_temporary_files(folder):
            log.warning("removed %s, left half-written by a server that was killed", path)
        try:
            self._check_layout(folder)
            segment = self._restore(folder)
        except ValueError as error:  # a manifest, checkpoint or logged batch that does not fit
            raise FolderUnusable(str(error)) from None
        self._wal = durability.WriteAheadLog(folder, segment, fsync=fsync)
        try:  # once the segment exists: a restart that misses it knows data may be lost
            durability.write_manifest(folder, self._layout(), segment=segment)
        except BaseException:
            self._wal.close()
            raise
        for table in self.tables.values():  # after the restore: replaying logs nothing
            table.log_samples(self._log_samples)

    def _log_samples(self, table: str, items: int) -> None:
        """Logs a sampled batch (the caller holds its table's lock, as a checkpoint's
        snapshot does: a batch is counted in the checkpoint or logged after it).

        A failed append (a full disk) still serves the batch: the data is safe and the
        learner goes on; only a restart before the next checkpoint would count fewer
        samples than were served. It is logged and counted.
        """
        if self._wal is None:
            return
        try:
            self._wal.append_samples(table, items)
        except StorageError as error:
            self.durability.unlogged_samples += items
            log.warning(
                "table '%s': %s; %d sampled items are counted in memory only until the next "
                "checkpoint", table, error, self.durability.unlogged_samples,
            )  # fmt: skip

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
        admits an insert now and the call is still `alive()`; all are logged (in one
        append) before any is stored. `blocked_s` (time already waited) goes into the
        tables' stats.

        Returns:
            (items stored, batches dropped as resends), or None while a rate limiter
            says wait (nothing was stored; try again after a change).

        Raises:
            CallEnded: `alive()` was false when the batches could have been stored.
            StorageError: the log append failed; nothing was stored (nor logged).
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
            if self._wal is not None and fresh:
                records = [(s.table, s.writer, s.sequence, s.payload) for s in fresh]
                try:
                    self._wal.append_all(records)
                except StorageError:
                    self.durability.log_append_failures += 1
                    raise  # before the rows go in: nothing unacknowledged is served
            stored = sum(targets[s.table].store(s.prepared, writer=s.writer) for s in fresh)
            for writer, sequence in high.items():
                self.writers.ack(writer, sequence)
            for name in used:
                targets[name].stats.insert_blocked_s += blocked_s
        return stored, dropped

    def checkpoint(self) -> Optional[Path]:
        """Snapshots all tables consistently, then writes them without blocking samples.

        Raises:
            StorageError: the checkpoint could not be written (counted and logged); the
                log still holds every insert since the previous checkpoint.
        """
        if self.checkpoint_dir is None or self._wal is None:
            return None
        with self._checkpoint_lock:
            try:
                with ExitStack() as stack:
                    for name in sorted(self.tables):
                        stack.enter_context(self.tables[name].lock)
                    stack.enter_context(self._acked_lock)
                    snapshots = {name: t.snapshot() for name, t in self.tables.items()}
                    acked = self.writers.snapshot()
                    segment = self._wal.rotate()
                # Locks released: inserts and samples go on while the files are written.
                durability.write_manifest(self.checkpoint_dir, self._layout(), segment=segment)
                path = durability.write_checkpoint(self.checkpoint_dir, snapshots, acked, segment)
            except (OSError, StorageError) as error:
                self.durability.checkpoint_failures += 1
                log.error(
                    "checkpoint failed (%s); the log keeps every insert since the last one", error
                )
                raise StorageError(f"checkpoint failed ({error})") from error
            self.durability.checkpoints += 1
            try:
                durability.prune(self.checkpoint_dir)
            except OSError as error:
                log.warning("could not delete old checkpoints or log segments (%s)", error)
        log.info("checkpoint written to %s", path)
        return path

    # ------------------------------------------------------------- restart

    def _layout(self) -> dict[str, Any]:
        """What a restart must not change: each table's signature and size."""
        return {
            name: {"signature": json.loads(t.signature.to_json()), "max_size": t.max_size}
            for name, t in self.tables.items()
        }

    def _check_layout(self, folder: Path) -> None:
        """Refuses a folder whose tables were stored under another signature or size."""
        recorded = durability.read_manifest(folder)
        if recorded is None:
            has_data = durability.checkpoint_numbers(folder) or any(
                durability.segment_path(folder, n).stat().st_size
                for n in durability.segment_numbers(folder)
            )
            if has_data:
                raise ValueError(
                    f"{folder} holds replay data but no {durability.MANIFEST}: it was written "
                    "by an earlier graft version (or the file was removed). Serve it with that "
                    "version, or start with an empty --checkpoint-dir"
                )
            return
        changes = []
        for name, now in self._layout().items():
            before = recorded.get(name)
            if before is None:
                continue  # a new table
            if before["signature"] != now["signature"]:
                changes.append(
                    f"table '{name}' signature {json.dumps(before['signature'])} is now "
                    f"{json.dumps(now['signature'])}"
                )
            if before["max_size"] != now["max_size"]:
                changes.append(
                    f"table '{name}' max_size {before['max_size']} is now {now['max_size']}"
                )
        if changes:
            raise ValueError(
                f"{folder} holds data stored under another table config: {'; '.join(changes)}. "
                "Its rows would be served cast or repeated, so a restart must keep each "
                "table's signature and max_size: restore the config, or start with another "
                "--checkpoint-dir"
            )

    def _restore(self, folder: Path) -> int:
        """Loads the newest readable checkpoint and replays the log after it; returns the
        number of the log segment to start.

        A checkpoint that fails its checksums is set aside and the one before it used,
        with the longer log after it: nothing acknowledged is lost on the way back. Every
        log segment from the base checkpoint's own up to the newest one known to have been
        started (on disk, named by a checkpoint or by `tables.json`) must be there: a
        missing one may have held acknowledged inserts, so that way back is not whole.
        """
        segments = durability.segment_numbers(folder)
        checkpoints = durability.checkpoint_numbers(folder)
        newest = max([*segments, *checkpoints, durability.started_segment(folder)])
        damaged: list[Path] = []
        reasons: list[str] = []
        # The way back from an empty start is whole while the log reaches its first segment.
        empty_start_whole = not checkpoints or (bool(segments) and segments[0] == 1)
        bases: list[Optional[int]] = [*reversed(checkpoints)]
        if empty_start_whole:
            bases.append(None)
        for base in bases:
            first = base if base is not None else 1
            missing = sorted(set(range(first, newest + 1)) - set(segments))
            if missing:
                reasons.append(
                    f"log segments {missing} of {first}..{newest} (from "
                    f"{'checkpoint ' + str(base) if base is not None else 'the start'}) "
                    "are missing"
                )
                continue
            found: Optional[durability.Checkpoint] = None
            if base is not None:
                path = durability.checkpoint_path(folder, base)
                try:
                    found = durability.read_checkpoint(path)
                except durability.DamagedCheckpoint as error:
                    log.warning("%s is unreadable (%s); trying the one before it", path.name, error)
                    reasons.append(f"{path.name} is unreadable ({error})")
                    damaged.append(path)
                    continue
            replayed = self._load(folder, found, [s for s in segments if s >= first])
            break
        else:
            raise ValueError(
                f"{folder}: no complete way back to the acknowledged data: "
                f"{'; '.join(reasons)}. Nothing was changed; move the folder aside to start "
                "with an empty table"
            )
        for path in damaged:
            path.rename(path.with_name(path.name + ".damaged"))
        self.durability.damaged_checkpoints = len(damaged)
        source = (
            durability.checkpoint_path(folder, base).name if base is not None else "no checkpoint"
        )
        items = found.items if found is not None else 0
        if damaged:
            log.warning(
                "fell back past %d unreadable checkpoint(s) (kept as *.damaged): recovered %d "
                "items from %s and %d logged batches after it", len(damaged), items, source,
                replayed,
            )  # fmt: skip
        elif found is not None or replayed:
            log.info(
                "restored %d items from %s and %d logged batches after it", items, source, replayed
            )
        for t in self.tables.values():
            if t.stats.inserts or t.stats.samples:
                log.info(
                    "table '%s' restored: %d items, %d inserted, %d sampled",
                    t.name, t.size, t.stats.inserts, t.stats.samples,
                )  # fmt: skip
        return max(max(segments, default=0), base or 0) + 1

    def _load(
        self, folder: Path, found: Optional[durability.Checkpoint], segments: list[int]
    ) -> int:
        """Restores a checkpoint (if any) and replays the log segments; returns batches replayed."""
        if found is not None:
            for name, state in found.tables.items():
                if name in self.tables:
                    self.tables[name].restore(state)
                else:
                    log.warning("checkpoint has table '%s', which is not configured", name)
            self.writers.restore(found.acked)
        replayed = 0
        for number in segments:
            path = durability.segment_path(folder, number)
            damage = durability.LogDamage()
            for record in durability.read_segment(path, damage, decode_batch):
                if isinstance(record, durability.Sampled):
                    if record.table in self.tables:
                        self.tables[record.table].stats.samples += record.items
                    continue
                writer, sequence = record.writer, record.sequence
                if record.table not in self.tables:
                    continue
                if writer and sequence <= self.writers.acked(writer):
                    continue
                self.tables[record.table].insert(record.batch, writer=writer, rate_limited=False)
                if writer:
                    self.writers.ack(writer, sequence)
                replayed += 1
            if damage.records:
                log.warning(
                    "%s: skipped %d damaged record(s) (%d bytes), %s: their batches are lost, "
                    "the records after them were read", path.name, damage.records, damage.bytes,
                    "; ".join(damage.notes),
                )  # fmt: skip
            if damage.torn_bytes:
                log.info(
                    "%s: ignored an incomplete last record (%d bytes), a write cut short and "
                    "never acknowledged", path.name, damage.torn_bytes,
                )  # fmt: skip
            self.durability.damaged_log_records += damage.records
        return replayed

    def close(self) -> None:
        if self._wal is not None:
            self._wal.close()
        if self._folder_lock is not None:
            self._folder_lock.close()  # releases the folder
