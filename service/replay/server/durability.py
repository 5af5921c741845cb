"""Durable replay state: atomic checkpoints plus a write-ahead log of acknowledged inserts.

An insert is acknowledged only after its record is in the log (flushed to the OS, so
it survives the server process being killed). A checkpoint snapshots every table and
starts a new log segment; restoring loads the newest checkpoint and replays the
segments written after it. Replay goes through the normal de-duplicating insert, so
a record that is both in a checkpoint and a log is still stored once.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Optional

import msgpack
import numpy as np

_HEADER = struct.Struct(">II")  # record length, crc32 of the record


def _fsync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class WriteAheadLog:
    """Append-only segments `wal-<n>.log` of (table, writer, sequence, payload) records."""

    def __init__(self, folder: Path, segment: int, *, fsync: bool = False) -> None:
        self.folder = folder
        self.fsync = fsync
        self.segment = segment
        self._file = open(self.path(segment), "ab")

    def path(self, segment: int) -> Path:
        return self.folder / f"wal-{segment:010d}.log"

    def append(self, table: str, writer: str, sequence: int, payload: bytes) -> None:
        record = msgpack.packb([table, writer, sequence, payload], use_bin_type=True)
        self._file.write(_HEADER.pack(len(record), zlib.crc32(record)) + record)
        self._file.flush()  # in the OS page cache: survives SIGKILL of this process
        if self.fsync:
            os.fsync(self._file.fileno())  # also survives power loss, at a latency cost

    def rotate(self) -> int:
        """Closes the current segment and starts the next; returns the new segment number."""
        self._file.close()
        self.segment += 1
        self._file = open(self.path(self.segment), "ab")
        return self.segment

    def close(self) -> None:
        self._file.close()


def segments(folder: Path, first: int) -> list[Path]:
    """Log segments numbered >= first, oldest first."""
    found = sorted(folder.glob("wal-*.log"))
    return [p for p in found if int(p.stem.split("-")[1]) >= first]


def read_segment(path: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """Yields records; stops quietly at a torn tail (a crash in the middle of a write)."""
    data = path.read_bytes()
    offset = 0
    while offset + _HEADER.size <= len(data):
        length, crc = _HEADER.unpack_from(data, offset)
        record = data[offset + _HEADER.size : offset + _HEADER.size + length]
        if len(record) < length or zlib.crc32(record) != crc:
            return
        table, writer, sequence, payload = msgpack.unpackb(record, raw=False)
        yield table, writer, sequence, payload
        offset += _HEADER.size + length


def write_checkpoint(
    folder: Path, tables: dict[str, dict[str, Any]], acked: dict[str, int], wal_segment: int
) -> Path:
    """Writes `checkpoint-<segment>.npz` atomically (temporary file, fsync, rename)."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {"acked": acked, "wal_segment": wal_segment, "tables": {}}
    for name, state in tables.items():
        meta["tables"][name] = state["meta"]
        for key, value in state.items():
            if key != "meta" and value is not None:
                arrays[f"{name}/{key}"] = np.asarray(value)
    arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    path = folder / f"checkpoint-{wal_segment:010d}.npz"
    tmp = folder / f".{path.name}.tmp"
    with open(tmp, "wb") as f:
        buffer = io.BufferedWriter(f, buffer_size=1 << 20)
        # numpy's stub reads `**arrays` as possibly filling its `allow_pickle: bool`.
        np.savez(buffer, **arrays)  # type: ignore[arg-type]
        buffer.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(folder)
    return path


def read_latest_checkpoint(
    folder: Path,
) -> Optional[tuple[dict[str, dict[str, Any]], dict[str, int], int]]:
    """Returns (per-table state, acked sequences, first log segment after it), or None."""
    found = sorted(folder.glob("checkpoint-*.npz"))
    if not found:
        return None
    with np.load(found[-1], allow_pickle=False) as data:
        meta = json.loads(bytes(data["__meta__"]).decode())
        tables: dict[str, dict[str, Any]] = {
            name: {"meta": table_meta} for name, table_meta in meta["tables"].items()
        }
        for key in data.files:
            if key != "__meta__":
                name, field = key.split("/", 1)
                tables[name][field] = data[key]
    return tables, {w: int(s) for w, s in meta["acked"].items()}, int(meta["wal_segment"])


def prune(folder: Path, keep_from_segment: int) -> None:
    """Deletes checkpoints and log segments older than the newest checkpoint."""
    for path in folder.glob("checkpoint-*.npz"):
        if int(path.stem.split("-")[1]) < keep_from_segment:
            path.unlink()
    for path in folder.glob("wal-*.log"):
        if int(path.stem.split("-")[1]) < keep_from_segment:
            path.unlink()
