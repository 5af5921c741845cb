"""The replay service's pure-Python core: named tables, exactly-once inserts, durability.

The gRPC servicer (service/replay/server/servicer.py) only decodes, calls this, and encodes.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from service.replay.codec import Batch, decode_batch
from service.replay.server import durability
from service.replay.server.durability import StorageError
from service.replay.server.table import Table

log = logging.getLogger(__name__)


class UnknownTable(KeyError):
    """A request named a table the server does not have."""

    def __str__(self) -> str:
        return str(self.args[0])


@dataclass
class DurabilityStats:
    """What the durable state went through; the metrics export these."""

    checkpoints: int = 0
    checkpoint_failures: int = 0
    log_append_failures: int = 0
    damaged_log_records: int = 0
    """Log records skipped at start-up because their checksum failed."""
    damaged_checkpoints: int = 0
    """Checkpoints found unreadable at start-up (set aside as `*.damaged`)."""


class ReplayCore:
    """Holds the tables and, per writer, the highest batch sequence number stored.

    With a `checkpoint_dir`, every insert is logged before it is stored and acknowledged,
    and the state is restored from that folder on construction.

    Raises:
        ValueError: the folder holds data of another table config, or data that cannot
            be restored whole (the message says what and how to proceed).
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
        self.durability = DurabilityStats()
        self.checkpoint_dir = Path(checkpoint_dir) if checkpoint_dir else None
        self._wal: Optional[durability.WriteAheadLog] = None
        if self.checkpoint_dir is not None:
            self.checkpoint_dir.mkdir(parents=True, exist_ok=True)
            for path in durability.remove_temporary_files(self.checkpoint_dir):
                log.warning("removed %s, left half-written by a server that was killed", path)
            self._check_layout(self.checkpoint_dir)
            segment = self._restore(self.checkpoint_dir)
            durability.write_manifest(self.checkpoint_dir, self._layout())
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

        Raises:
            StorageError: the log append failed; nothing was stored.
        """
        target = self.table(table)
        if writer_id:
            with self._acked_lock:
                if sequence <= self.acked.get(writer_id, 0):
                    return None

        def log_then_store() -> None:  # under the table lock, in the table's insert order
            with self._acked_lock:
                if self._wal is not None:
                    try:
                        self._wal.append(table, writer_id, sequence, payload)
                    except StorageError:
                        self.durability.log_append_failures += 1
                        raise  # before the rows go in: nothing unacknowledged is served
                if writer_id:
                    self.acked[writer_id] = max(sequence, self.acked.get(writer_id, 0))

        return target.insert(batch, timeout=timeout, writer=writer_id, before_store=log_then_store)

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
                    acked = dict(self.acked)
                    segment = self._wal.rotate()
                # Locks released: inserts and samples go on while the file is written.
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
        with the longer log after it: nothing acknowledged is lost on the way back.
        """
        segments = durability.segment_numbers(folder)
        checkpoints = durability.checkpoint_numbers(folder)
        damaged: list[Path] = []
        reasons: list[str] = []
        # The way back from an empty start is whole while the log reaches its first segment.
        empty_start_whole = not checkpoints or (bool(segments) and segments[0] == 1)
        bases: list[Optional[int]] = [*reversed(checkpoints)]
        if empty_start_whole:
            bases.append(None)
        for base in bases:
            first = base if base is not None else 1
            missing = sorted(set(range(first, max(segments, default=0) + 1)) - set(segments))
            if missing:
                reasons.append(f"log segments {missing} after segment {first} are missing")
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
            self.acked = found.acked
        replayed = 0
        for number in segments:
            path = durability.segment_path(folder, number)
            damage = durability.LogDamage()
            for table, writer, sequence, payload in durability.read_segment(path, damage):
                if table not in self.tables:
                    continue
                if writer and sequence <= self.acked.get(writer, 0):
                    continue
                self.tables[table].insert(decode_batch(payload), writer=writer, rate_limited=False)
                if writer:
                    self.acked[writer] = sequence
                replayed += 1
            if damage.records:
                log.warning(
                    "%s: skipped %d damaged record(s) (%d bytes): their batches are lost, the "
                    "records after them were read", path.name, damage.records, damage.bytes,
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
