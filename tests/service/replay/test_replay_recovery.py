"""Restarts never serve wrong data: changed configs, damaged logs and checkpoints, full disks.

Every test runs real server processes on loopback against a checkpoint folder it then
damages or constrains the way a crash, a bad disk or an operator would.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Optional

import msgpack
import numpy as np
import pytest

from graft.replay_host.process import EXIT_FOLDER_UNUSABLE, ReplayProcess
from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch
from service.replay.errors import ReplayError
from service.replay.server import durability
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, read_all, scalar_batch
from tests.tools.exec_with import command as exec_with


def table(**overrides) -> list[dict]:
    spec = {"name": "log", "max_size": 1000, "sampler": "fifo", "signature": SCALAR_SIGNATURE}
    return [{**spec, **overrides}]


def durable(folder: Path, tables: Optional[list[dict]] = None, *extra: str) -> ReplayProcess:
    return ReplayProcess(tables or table(), extra_args=["--checkpoint-dir", str(folder), *extra])


class Started:
    """A server process started directly (with a file-size limit, or expected to refuse)."""

    def __init__(
        self,
        tables: list[dict],
        folder: Path,
        *extra: str,
        file_size_limit: Optional[int] = None,
        timeout_s: float = 60.0,
    ) -> None:
        run = folder.parent / f"run-{time.monotonic_ns()}"
        run.mkdir()
        config, ready, self.log_path = run / "tables.json", run / "ready.json", run / "log"
        config.write_text(json.dumps({"tables": tables}))
        limit = [] if file_size_limit is None else ["--file-size-limit", str(file_size_limit)]
        limited = exec_with(*limit)  # the limit applies to the server only
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(
                [*limited, sys.executable, "-m", "graft.cli.replay", "serve",
                 "--config", str(config), "--port", "0", "--ready-file", str(ready),
                 "--checkpoint-dir", str(folder), *extra],
                stdout=log, stderr=subprocess.STDOUT,
            )  # fmt: skip
        deadline = time.monotonic() + timeout_s
        while not ready.exists() and self.process.poll() is None:
            assert time.monotonic() < deadline, "the server neither started nor exited"
            time.sleep(0.05)
        self.address = json.loads(ready.read_text())["address"] if ready.exists() else None

    @property
    def log(self) -> str:
        return self.log_path.read_text()

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            # Only a guard against a hang: `make test` runs this file niced beside the
            # real-time tests, whose Ray nodes (nice -10) can hold it off the cores.
            self.process.wait(120)


def refusal(tables: list[dict], folder: Path) -> str:
    """Starts a server that must refuse to start; returns what it printed."""
    server = Started(tables, folder)
    if server.address is not None:
        server.stop()
        pytest.fail("the server started instead of refusing")
    assert server.process.returncode != 0
    return server.log


# ---------------------------------------------------------------- config changes


@pytest.mark.parametrize("stop", ["graceful", "sigkill"])
@pytest.mark.parametrize(
    "change, named",
    [
        ({"signature": {**SCALAR_SIGNATURE, "x": {"dtype": "int32", "shape": []}}}, "<i4"),
        ({"max_size": 300}, "max_size"),
    ],
    ids=["dtype", "max_size"],
)
@pytest.mark.service
def test_restart_refuses_a_changed_signature_or_size(tmp_path, stop, change, named):
    """Stopped gracefully, everything is in a checkpoint and the log is empty; SIGKILLed,
    everything is in the log. Either way an edited table config is refused, never
    served wrapped or repeated."""
    folder = tmp_path / "replay"
    server = durable(folder)
    ReplayClient(server.address).insert("log", scalar_batch(np.arange(900) * 2**40))
    if stop == "sigkill":
        server.kill()
    server.stop()
    server = Started(table(**change), folder)
    assert server.address is None, "the server started instead of refusing"
    assert server.process.returncode == EXIT_FOLDER_UNUSABLE  # a launcher may move it aside
    message = server.log
    assert "graft replay serve:" in message and named in message
    assert "Traceback" not in message
    with durable(folder) as server:  # the original config still restores everything
        stored = read_all(ReplayClient(server.address), "log")
        np.testing.assert_array_equal(stored, np.arange(900) * 2**40)


# ---------------------------------------------------------------- a damaged log


def _kill_after_batches(folder: Path, batches: int) -> None:
    """One writer inserts `batches` numbered batches of 10; the server is then SIGKILLed,
    so every batch is in the log only."""
    server = durable(folder, table(max_size=10_000))
    client = ReplayClient(server.address, writer_id="w")
    for i in range(batches):
        client.insert("log", scalar_batch(np.arange(i * 10, i * 10 + 10)))
    server.kill()
    server.stop()


@pytest.mark.parametrize("where", ["header", "payload"])
@pytest.mark.service
def test_flipped_byte_in_one_log_record_loses_that_record_only(tmp_path, where):
    folder = tmp_path / "replay"
    _kill_after_batches(folder, 10)
    [segment] = [p for p in folder.glob("wal-*.log") if p.stat().st_size]
    data = bytearray(segment.read_bytes())
    record = len(data) // 10  # ten records of equal size
    at = 5 * record + (1 if where == "header" else record // 2)
    data[at] ^= 0xFF
    segment.write_bytes(bytes(data))

    server = Started(table(max_size=10_000), folder)
    assert server.address is not None, server.log
    client = ReplayClient(server.address)
    stored = read_all(client, "log")
    expected = np.concatenate([np.arange(i * 10, i * 10 + 10) for i in range(10) if i != 5])
    np.testing.assert_array_equal(stored, expected)  # the nine others, each once
    assert "skipped 1 damaged record" in server.log
    # The writer's sequence survived: a resend of batch 10 is recognised, batch 11 is new.
    for sequence, stored_items in ((10, 0), (11, 10)):
        request = replay_pb2.InsertRequest(
            table="log", batch=encode_batch(scalar_batch(range(10))), writer_id="w",
            sequence=sequence,
        )  # fmt: skip
        assert client.stub.Insert(iter([request])).items_inserted == stored_items
    server.stop()


@pytest.mark.service
def test_a_record_whose_checksum_holds_but_payload_does_not_decode_loses_that_record_only(
    tmp_path,
):
    """A record that is not a batch is skipped like one that fails its checksum, and the
    warning names the file and the offset of each."""
    folder = tmp_path / "replay"
    _kill_after_batches(folder, 3)
    [segment] = [p for p in folder.glob("wal-*.log") if p.stat().st_size]
    bad = msgpack.packb(["log", "w", 4, b"\xc1 not a batch"], use_bin_type=True)
    at = segment.stat().st_size
    with open(segment, "ab") as f:  # a fourth record, checksums and all, then a fifth good one
        f.write(durability._framed(bad))
        good = ["log", "w", 5, encode_batch(scalar_batch(range(50, 60)))]
        f.write(durability._framed(msgpack.packb(good, use_bin_type=True)))

    server = Started(table(max_size=10_000), folder)
    try:
        assert server.address is not None, server.log
        stored = read_all(ReplayClient(server.address), "log")
    finally:
        server.stop()
    np.testing.assert_array_equal(stored, np.r_[np.arange(30), np.arange(50, 60)])
    assert f"{segment.name}: skipped 1 damaged record(s)" in server.log
    assert f"at offset {at} (payload is not valid msgpack" in server.log


# ---------------------------------------------------------------- missing log segments


def _checkpoint_then_kill(folder: Path) -> Path:
    """1000 items in a checkpoint, then 500 in the log after it; the server SIGKILLed.
    Returns the log segment that holds the 500 (the newest non-empty one)."""
    server = durable(folder, table(max_size=10_000))
    client = ReplayClient(server.address, writer_id="w")
    client.insert("log", scalar_batch(range(1000)))
    client.checkpoint()
    for i in range(5):
        client.insert("log", scalar_batch(range(1000 + 100 * i, 1100 + 100 * i)))
    server.kill()
    server.stop()
    return max(p for p in folder.glob("wal-*.log") if p.stat().st_size)


def _restart_then_kill(folder: Path) -> Path:
    """500 items logged, a SIGKILL, a restart (a new segment), 500 more, a SIGKILL; no
    checkpoint. Returns the segment that holds the second 500 (the newest)."""
    for start in (0, 500):
        server = durable(folder, table(max_size=10_000))
        ReplayClient(server.address).insert("log", scalar_batch(range(start, start + 500)))
        server.kill()
        server.stop()
    return max(p for p in folder.glob("wal-*.log") if p.stat().st_size)


@pytest.mark.parametrize("fill", [_checkpoint_then_kill, _restart_then_kill])
@pytest.mark.service
def test_a_deleted_newest_log_segment_is_refused_not_skipped(tmp_path, fill):
    """Acknowledged inserts in the newest segment: with that segment gone the folder has
    no way back whole, and the server refuses to start naming it, as for any missing
    segment, instead of serving the items before it as if nothing were lost."""
    folder = tmp_path / "replay"
    newest = fill(folder)
    newest.unlink()
    server = Started(table(max_size=10_000), folder)
    server.stop()
    assert server.address is None, "the server started without the acknowledged 500 items"
    assert server.process.returncode == EXIT_FOLDER_UNUSABLE
    assert f"log segments [{durability._number(newest)}]" in server.log
    assert "are missing" in server.log and "Traceback" not in server.log


# ---------------------------------------------------------------- damaged checkpoints


@pytest.mark.parametrize("damage", ["truncated", "flipped"])
@pytest.mark.service
def test_damaged_newest_checkpoint_falls_back_to_the_previous_one(tmp_path, damage):
    folder = tmp_path / "replay"
    server = durable(folder)
    client = ReplayClient(server.address)
    client.insert("log", scalar_batch(range(0, 100)))
    client.checkpoint()
    client.insert("log", scalar_batch(range(100, 200)))
    newest = Path(client.checkpoint())
    client.insert("log", scalar_batch(range(200, 300)))  # in the log only
    server.kill()
    server.stop()
    data = bytearray(newest.read_bytes())
    if damage == "truncated":
        data = data[: len(data) // 2]
    else:  # one bit of the stored values (of column x or of the keys: both are 100..199)
        data[data.find(np.arange(150, 152).tobytes()) + 3] ^= 0x10
    newest.write_bytes(bytes(data))

    server = Started(table(), folder)
    assert server.address is not None, server.log
    stored = read_all(ReplayClient(server.address), "log")
    np.testing.assert_array_equal(stored, np.arange(300))
    assert f"{newest.name} is unreadable" in server.log
    assert "recovered 100 items from checkpoint-" in server.log
    assert "and 2 logged batches after it" in server.log
    server.stop()


@pytest.mark.service
def test_half_written_checkpoint_files_are_removed_at_start(tmp_path):
    folder = tmp_path / "replay"
    folder.mkdir()
    stale = folder / ".checkpoint-0000000007.npz.tmp"  # a server killed while writing
    stale.write_bytes(b"PK\x03\x04 half a zip file")
    with durable(folder) as server:
        ReplayClient(server.address).insert("log", scalar_batch(range(5)))
    assert not stale.exists()


# ---------------------------------------------------------------- a full disk


@pytest.mark.service
def test_failed_log_append_stores_nothing_and_the_server_keeps_serving(tmp_path):
    """The server may write no file past 64 KiB (a full disk, as a file-size limit): the
    insert whose log append fails is refused and none of its rows is ever served."""
    folder = tmp_path / "replay"
    server = Started(table(max_size=100_000), folder, file_size_limit=64 * 1024)
    assert server.address is not None, server.log
    client = ReplayClient(server.address, max_retries=0)
    acked, failed = [], None
    for i in range(100):
        try:
            client.insert("log", scalar_batch(np.arange(i * 500, i * 500 + 500)))
            acked.append(i)
        except ReplayError as error:
            failed = error
            break
    assert failed is not None, "the file-size limit was never reached"
    expected = np.concatenate([np.arange(i * 500, i * 500 + 500) for i in acked])
    np.testing.assert_array_equal(read_all(client, "log"), expected)
    assert "No space" in str(failed) or "too large" in str(failed)
    server.stop()
    with durable(
        folder, table(max_size=100_000)
    ) as restarted:  # no limit: what was acknowledged, nothing more
        np.testing.assert_array_equal(read_all(ReplayClient(restarted.address), "log"), expected)


def _segments(folder: Path) -> int:
    return max((int(p.stem.split("-")[1]) for p in folder.glob("wal-*.log")), default=0)


def _wait_for(what: str, done, server: Started, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done():
        assert server.process.poll() is None, f"the server died waiting for {what}:\n{server.log}"
        assert time.monotonic() < deadline, f"no {what}:\n{server.log}"
        time.sleep(0.05)


@pytest.mark.service
def test_failed_periodic_checkpoint_keeps_the_server_running(tmp_path):
    """Checkpoints grow past a 256 KiB file-size limit while each log segment stays under
    it: every periodic checkpoint then fails, and the server goes on serving and logging."""
    folder = tmp_path / "replay"
    metrics = free_port()
    server = Started(
        table(max_size=100_000), folder, "--checkpoint-every-s", "0.2",
        "--metrics-port", str(metrics), file_size_limit=256 * 1024,
    )  # fmt: skip
    assert server.address is not None, server.log
    client = ReplayClient(server.address, max_retries=0)
    client.insert("log", scalar_batch(np.arange(0, 10_000)))  # a checkpoint of ~180 KB fits
    _wait_for("checkpoint", lambda: list(folder.glob("checkpoint-*.npz")), server)
    first = _segments(folder)
    _wait_for("rotation", lambda: _segments(folder) > first, server)
    client.insert("log", scalar_batch(np.arange(10_000, 20_000)))  # ~360 KB: it cannot
    after = _segments(folder)
    _wait_for("two more checkpoint attempts", lambda: _segments(folder) > after + 1, server)

    text = urllib.request.urlopen(f"http://127.0.0.1:{metrics}/metrics", timeout=10).read()
    failures = [
        float(line.split()[-1])
        for line in text.decode().splitlines()
        if line.startswith("graft_replay_checkpoint_failures_total")
    ]
    assert failures and failures[0] >= 1
    assert client.insert("log", scalar_batch(np.arange(20_000, 20_010))) == 10
    assert not list(folder.glob(".*.tmp")), "a failed checkpoint left its temporary file"
    server.stop()
    with durable(folder, table(max_size=100_000)) as restarted:
        np.testing.assert_array_equal(
            read_all(ReplayClient(restarted.address), "log"), np.arange(20_010)
        )


@pytest.mark.service
def test_a_folder_of_the_previous_format_is_restored(tmp_path):
    """Format 2 (a log of inserts only) is still read: a folder written by the previous
    version restores, and is written on in the current format."""
    folder = tmp_path / "replay"
    _kill_after_batches(folder, 3)
    manifest = json.loads((folder / "tables.json").read_text())
    (folder / "tables.json").write_text(json.dumps({**manifest, "format": 2}))
    with durable(folder, table(max_size=10_000)) as server:
        stored = read_all(ReplayClient(server.address), "log")
    np.testing.assert_array_equal(stored, np.arange(30))
    assert json.loads((folder / "tables.json").read_text())["format"] == 3
