"""Durable replay state on disk: a write-ahead log of acknowledged inserts and of sample
counts, checksummed checkpoints, and the manifest of the tables a folder holds.

Folder layout (`--checkpoint-dir`):

    tables.json               each table's signature and max_size (a restart must keep them)
    checkpoint-<n>.npz        every table at the moment log segment n was started
    wal-<n>.log               the inserts and samples after that moment, one checksummed
                              record each

An insert is acknowledged only after its record is in the log (flushed to the OS, so it
survives the server process being killed). A sampled batch is logged as its table and
item count before it is counted and sent, so a restart restores the sample count the rate
limiter holds the ratio with. The two newest checkpoints are kept, with
every log segment from the older one on, so a damaged newest checkpoint still leaves a
complete way back: the previous checkpoint plus the log after it.
"""

from __future__ import annotations

import io
import json
import os
import struct
import threading
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, Optional, TypeVar

import msgpack
import numpy as np

FORMAT = 3
"""Bumped whenever the files change shape; what this version writes."""

READABLE_FORMATS = (2, 3)
"""Formats this version reads (2: the log holds inserts only); others are refused."""

MANIFEST = "tables.json"

# A log record: magic, record length, CRC-32 of the record, CRC-32 of the 12 bytes before.
# The header's own checksum makes its length trustworthy, so a damaged record is skipped
# whole; a damaged header is skipped by finding the next record whose checksums hold.
_MAGIC = b"GWAL"
_HEADER = struct.Struct(">4sIII")

Record = tuple[str, str, int, bytes]
"""An insert: (table, writer id, sequence, encoded batch)"""

B = TypeVar("B")


@dataclass(frozen=True)
class Sampled:
    """A sample record: `items` more items were sampled from `table`."""

    table: str
    items: int


class StorageError(RuntimeError):
    """The log or a checkpoint could not be written; the operation changed nothing."""


class DamagedCheckpoint(ValueError):
    """A checkpoint file is truncated, fails its checksums or does not parse."""


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _number(path: Path) -> int:
    return int(path.name.split("-")[1].split(".")[0])


def segment_numbers(folder: Path) -> list[int]:
    """Numbers of the log segments in `folder`, oldest first."""
    return sorted(_number(p) for p in folder.glob("wal-*.log"))


def checkpoint_numbers(folder: Path) -> list[int]:
    """Numbers of the checkpoints in `folder` (the log segment each starts), oldest first."""
    return sorted(_number(p) for p in folder.glob("checkpoint-*.npz"))


def segment_path(folder: Path, number: int) -> Path:
    return folder / f"wal-{number:010d}.log"


def checkpoint_path(folder: Path, number: int) -> Path:
    return folder / f"checkpoint-{number:010d}.npz"


# ------------------------------------------------------------------------ the log


class WriteAheadLog:
    """Append-only segments `wal-<n>.log` of insert records (table, writer, sequence,
    payload) and sample records (table, items); thread-safe."""

    def __init__(self, folder: Path, segment: int, *, fsync: bool = False) -> None:
        self.folder = folder
        self.fsync = fsync
        self.segment = segment
        self._file = open(segment_path(folder, segment), "ab", buffering=0)
        self._end = os.fstat(self._file.fileno()).st_size
        self._broken: Optional[str] = None
        # Inserts append under the writer map's lock, samples under their table's only.
        self._lock = threading.Lock()

    def append(self, table: str, writer: str, sequence: int, payload: bytes) -> None:
        """Appends one record, or raises StorageError leaving the segment as it was."""
        self.append_all([(table, writer, sequence, payload)])

    def append_all(self, records: list[Record]) -> None:
        """Appends records in one write, all or none: raises StorageError leaving the
        segment as it was."""
        packed = [msgpack.packb(list(r), use_bin_type=True) for r in records]
        with self._lock:
            self._write(b"".join(map(_framed, packed)), sync=self.fsync)

    def append_samples(self, table: str, items: int) -> None:
        """Appends a sample record, or raises StorageError leaving the segment as it was.

        Never fsynced on its own (a sample costs far less than a disk flush): killing the
        process never loses it; with `fsync`, a power loss may lose the sample records
        written since the last insert.
        """
        record = _framed(msgpack.packb([table, items], use_bin_type=True))
        with self._lock:
            self._write(record, sync=False)

    def _write(self, data: bytes, *, sync: bool) -> None:
        if self._broken is not None:
            raise StorageError(
                f"the write-ahead log is unusable until the next checkpoint ({self._broken}); "
                "nothing was stored"
            )
        frame = memoryview(data)
        try:
            while frame:  # unbuffered: each write goes to the OS, which may take part of it
                frame = frame[self._file.write(frame) :]
            if sync:
                os.fsync(self._file.fileno())  # also survives power loss, at a latency cost
        except OSError as error:
            try:  # cut what part of the records reached the file: they were never acknowledged
                os.ftruncate(self._file.fileno(), self._end)
            except OSError as again:
                self._broken = f"cutting a partial record failed: {again}"
            raise StorageError(
                f"write-ahead log append failed ({error}); nothing was stored"
            ) from error
        self._end += len(data)

    def rotate(self) -> int:
        """Starts the next segment; returns its number. Raises StorageError, keeping the
        current segment, if the new one cannot be created."""
        with self._lock:
            try:
                following = open(segment_path(self.folder, self.segment + 1), "ab", buffering=0)
            except OSError as error:
                raise StorageError(f"cannot start a new log segment ({error})") from error
            self._file.close()
            self._file, self._end, self._broken = following, 0, None
            self.segment += 1
            return self.segment

    def close(self) -> None:
        with self._lock:
            self._file.close()


def _framed(record: bytes) -> bytes:
    """A packed record behind its header (magic, length, CRCs of record and header)."""
    head = _MAGIC + struct.pack(">II", len(record), zlib.crc32(record))
    return head + struct.pack(">I", zlib.crc32(head)) + record


MAX_DAMAGE_NOTES = 10
"""Damaged records whose offset and reason a warning lists (all are counted)."""


@dataclass
class LogDamage:
    """What reading log segments had to skip."""

    records: int = 0
    """Damaged records (or runs of records with a damaged header) skipped."""
    bytes: int = 0
    torn_bytes: int = 0
    """An incomplete last record: a write cut short by a crash, never acknowledged."""
    notes: list[str] = field(default_factory=list)
    """"at offset <n> (<reason>)" for the first MAX_DAMAGE_NOTES damaged records."""

    def skipped(self, at: int, size: int, reason: str) -> None:
        self.records += 1
        self.bytes += size
        if len(self.notes) < MAX_DAMAGE_NOTES:
            self.notes.append(f"at offset {at} ({reason})")


@dataclass(frozen=True)
class Inserted(Generic[B]):
    """An insert record, its batch decoded."""

    table: str
    writer: str
    sequence: int
    batch: B


def _frame(data: bytes, at: int) -> Optional[tuple[int, int, int]]:
    """(record start, record length, record CRC) of a header at `at` whose checksum holds."""
    if at + _HEADER.size > len(data):
        return None
    magic, length, crc, header_crc = _HEADER.unpack_from(data, at)
    if magic != _MAGIC or zlib.crc32(data[at : at + 12]) != header_crc:
        return None
    return at + _HEADER.size, length, crc


def _next_record(data: bytes, start: int) -> int:
    """Offset of the next record at or after `start` whose checksums both hold, or -1."""
    at = data.find(_MAGIC, start)
    while at >= 0:
        frame = _frame(data, at)
        if frame is not None:
            begin, length, crc = frame
            end = begin + length
            if end <= len(data) and zlib.crc32(data[begin:end]) == crc:
                return at
        at = data.find(_MAGIC, at + 1)
    return -1


def read_segment(
    path: Path, damage: LogDamage, decode: Callable[[bytes], B]
) -> Iterator[Inserted[B] | Sampled]:
    """Yields the records of one segment (inserts, their batches decoded by `decode`, and
    sample records), oldest first, skipping damaged ones.

    A record whose checksum fails, or whose checksum holds but whose fields or batch do
    not decode (`decode` raises ValueError), is skipped and noted in `damage` with its
    offset, and reading goes on with the next: one bad record loses that record's batch,
    never the ones after it. An incomplete last record is a write cut short; it is
    counted as torn.
    """
    data = path.read_bytes()
    at = 0
    while at < len(data):
        frame = _frame(data, at)
        if frame is None:
            following = _next_record(data, at + 1)
            if following < 0:
                if len(data) - at < _HEADER.size:
                    damage.torn_bytes += len(data) - at
                else:
                    damage.skipped(at, len(data) - at, "no header holds after it")
                return
            damage.skipped(at, following - at, "damaged header")
            at = following
            continue
        begin, length, crc = frame
        end = begin + length
        if end > len(data):
            damage.torn_bytes += len(data) - at
            return
        record = data[begin:end]
        start, at = at, end
        try:
            if zlib.crc32(record) != crc:
                raise ValueError("checksum fails")
            fields = msgpack.unpackb(record, raw=False)
            if len(fields) == 2:
                yield Sampled(str(fields[0]), int(fields[1]))
                continue
            table, writer, sequence, payload = fields
            found = Inserted(str(table), str(writer), int(sequence), decode(payload))
        except (ValueError, TypeError) as error:  # msgpack's errors are ValueErrors
            damage.skipped(start, _HEADER.size + length, str(error) or type(error).__name__)
            continue
        yield found


# ------------------------------------------------------------------ checkpoints


def _crc(array: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(array).view(np.uint8).reshape(-1).data)


def write_checkpoint(
    folder: Path, tables: dict[str, dict[str, Any]], acked: dict[str, int], wal_segment: int
) -> Path:
    """Writes `checkpoint-<segment>.npz` atomically (temporary file, fsync, rename), with a
    CRC-32 of every array. On failure the temporary file is removed and OSError raised."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {
        "format": FORMAT, "acked": acked, "wal_segment": wal_segment, "tables": {}, "crc32": {}
    }  # fmt: skip
    for name, state in tables.items():
        meta["tables"][name] = state["meta"]
        for key, value in state.items():
            if key != "meta" and value is not None:
                arrays[f"{name}/{key}"] = np.asarray(value)
    meta["crc32"] = {key: _crc(array) for key, array in arrays.items()}
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    path = checkpoint_path(folder, wal_segment)
    tmp = folder / f".{path.name}.tmp"
    try:
        with open(tmp, "wb") as f:
            buffer = io.BufferedWriter(f, buffer_size=1 << 20)
            # numpy's stub reads `**arrays` as possibly filling its `allow_pickle: bool`.
            np.savez(buffer, **arrays)  # type: ignore[arg-type]
            buffer.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        _fsync_dir(folder)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


@dataclass
class Checkpoint:
    """A checkpoint read back whole: per-table state, acked sequences, its log segment."""

    tables: dict[str, dict[str, Any]]
    acked: dict[str, int]
    wal_segment: int

    @property
    def items(self) -> int:
        return sum(len(state.get("keys", ())) for state in self.tables.values())


def read_checkpoint(path: Path) -> Checkpoint:
    """Reads and verifies a checkpoint; raises DamagedCheckpoint naming what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(bytes(data["__meta__"]).decode())
            if meta.get("format") not in READABLE_FORMATS:
                raise DamagedCheckpoint(
                    f"format {meta.get('format')}, expected one of {READABLE_FORMATS}"
                )
            expected: dict[str, int] = meta["crc32"]
            keys = [k for k in data.files if k != "__meta__"]
            if sorted(keys) != sorted(expected):
                raise DamagedCheckpoint("its arrays are not the ones its index lists")
            tables: dict[str, dict[str, Any]] = {
                name: {"meta": table_meta} for name, table_meta in meta["tables"].items()
            }
            for key in keys:
                array = data[key]
                if _crc(array) != expected[key]:
                    raise DamagedCheckpoint(f"array '{key}' fails its CRC-32")
                name, field = key.split("/", 1)
                tables[name][field] = array
        acked = {w: int(s) for w, s in meta["acked"].items()}
        return Checkpoint(tables, acked, int(meta["wal_segment"]))
    except DamagedCheckpoint:
        raise
    except Exception as error:  # a damaged zip or header fails in many ways; all mean unusable
        raise DamagedCheckpoint(f"{type(error).__name__}: {error}") from error


def prune(folder: Path) -> None:
    """Keeps the two newest checkpoints and every log segment from the older of them on."""
    kept = checkpoint_numbers(folder)[-2:]
    if len(kept) < 2:
        return  # one checkpoint: the log from the start is the way back to keep
    for number in checkpoint_numbers(folder):
        if number < kept[0]:
            checkpoint_path(folder, number).unlink()
    for number in segment_numbers(folder):
        if number < kept[0]:
            segment_path(folder, number).unlink()


def remove_temporary_files(folder: Path) -> list[Path]:
    """Deletes half-written files (`.<name>.tmp`) a killed server left; returns them."""
    stale = sorted(folder.glob(".*.tmp"))
    for path in stale:
        path.unlink()
    return stale


# -------------------------------------------------------------------- manifest


def started_segment(folder: Path) -> int:
    """The newest log segment a server started on this folder, as `tables.json` records
    it (0 if it records none): every segment up to it existed."""
    path = folder / MANIFEST
    try:
        return int(json.loads(path.read_text()).get("segment", 0))
    except (OSError, ValueError, AttributeError):
        return 0  # no manifest, or one read_manifest refuses with a reason


def read_manifest(folder: Path) -> Optional[dict[str, Any]]:
    """The folder's `tables.json` ({table: {"signature": ..., "max_size": ...}}), or None."""
    path = folder / MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
        if data.get("format") not in READABLE_FORMATS:
            raise ValueError(f"format {data.get('format')}, expected one of {READABLE_FORMATS}")
        tables: dict[str, Any] = data["tables"]
        return tables
    except (ValueError, KeyError, AttributeError) as error:
        raise ValueError(f"{path} is unreadable ({error})") from None


def write_manifest(folder: Path, tables: dict[str, Any], *, segment: int) -> None:
    """Writes `tables.json` atomically: the tables' layout and `segment`, the log segment
    now started (a restart then knows it must find it)."""
    path = folder / MANIFEST
    tmp = folder / f".{MANIFEST}.tmp"
    try:
        manifest = {"format": FORMAT, "tables": tables, "segment": segment}
        tmp.write_text(json.dumps(manifest, indent=1))
        os.replace(tmp, path)
        _fsync_dir(folder)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
