"""Durability on real server processes: checkpoints, SIGKILL, exactly-once resends."""

from __future__ import annotations

import ctypes
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient
from service.replay.errors import DeadlineExceeded
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, read_all, scalar_batch

pytestmark = [pytest.mark.service, pytest.mark.serial]  # servers restarted on their port

TABLE = [{"name": "log", "max_size": 1_000_000, "sampler": "fifo", "signature": SCALAR_SIGNATURE}]


SYS_TGKILL = 234  # x86-64's number of tgkill(2): a signal to one thread of a process


def durable_server(folder, port=0) -> ReplayProcess:
    return ReplayProcess(TABLE, port=port, extra_args=["--checkpoint-dir", str(folder)])


def test_checkpoint_restore_round_trip(tmp_path):
    with durable_server(tmp_path) as server:
        client = ReplayClient(server.address)
        client.insert("log", scalar_batch(range(100)))
        path = client.checkpoint()
        assert path.endswith(".npz")
        client.insert("log", scalar_batch(range(100, 150)))  # after the checkpoint: in the log
        client.close()
    with durable_server(tmp_path) as server:
        client = ReplayClient(server.address)
        np.testing.assert_array_equal(read_all(client, "log"), np.arange(150))
        [table] = client.info()
        assert table.inserts == 150
        client.close()
    assert not list(tmp_path.glob(".*.tmp")), "a temporary checkpoint file was left behind"


def test_episode_ends_are_kept_by_checkpoints_and_the_log(tmp_path):
    # An ended episode of 2 steps in the checkpoint, another in the log after it: after a
    # restart both still give windows of 3 that repeat their last step.
    table = [
        {"name": "w", "max_size": 100, "max_sequence_length": 3, "signature": SCALAR_SIGNATURE}
    ]
    extra = ["--checkpoint-dir", str(tmp_path)]
    with ReplayProcess(table, extra_args=extra) as server:
        client = ReplayClient(server.address)
        client.insert("w", scalar_batch([0, 1], ends=[False, True]))
        client.checkpoint()
        client.insert("w", scalar_batch([10, 11], ends=[False, True]))
        client.close()
        server.kill()  # no final checkpoint: the second episode comes back from the log
    with ReplayProcess(table, extra_args=extra) as server:
        client = ReplayClient(server.address)
        sample = client.sample("w", 200, sequence_length=3, timeout=5)
        client.close()
    windows = {tuple(w) for w in sample["x"].tolist()}
    assert windows == {(0, 1, 1), (1, 1, 1), (10, 11, 11), (11, 11, 11)}


def test_graceful_stop_writes_a_final_checkpoint(tmp_path):
    with durable_server(tmp_path) as server:
        ReplayClient(server.address).insert("log", scalar_batch(range(10)))
    [checkpoint] = tmp_path.glob("checkpoint-*.npz")
    after = [p for p in tmp_path.glob("wal-*.log") if p.stem[4:] >= checkpoint.stem[11:]]
    assert after and sum(p.stat().st_size for p in after) == 0  # all in the checkpoint


def test_a_stop_signal_any_thread_takes_still_stops_it_at_once(tmp_path):
    """The kernel may hand a SIGTERM to any of the server's threads (gRPC's, its own). A
    `graft replay serve` run by hand (no --exit-with-parent) slept on until its next
    periodic checkpoint, 300 s away, when the main thread was not the one."""
    config = tmp_path / "tables.json"
    config.write_text(json.dumps({"tables": TABLE}))
    ready = tmp_path / "ready.json"
    state = tmp_path / "state"
    command = [
        sys.executable, "-m", "graft.cli.replay", "serve", "--config", str(config),
        "--port", "0", "--ready-file", str(ready), "--checkpoint-dir", str(state),
    ]  # fmt: skip
    server = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        while not ready.exists():
            assert server.poll() is None, "the server did not start"
            time.sleep(0.05)
        threads = sorted(int(t.name) for t in Path(f"/proc/{server.pid}/task").iterdir())
        other = next(t for t in threads if t != server.pid)  # not the main thread
        tgkill = ctypes.CDLL(None, use_errno=True).syscall
        assert tgkill(SYS_TGKILL, server.pid, other, signal.SIGTERM) == 0, ctypes.get_errno()
        assert server.wait(30.0) == 0
    finally:
        server.kill()
        server.wait()
    assert list(state.glob("checkpoint-*.npz"))  # stopped gracefully


def test_sigkill_mid_stream_loses_and_doubles_nothing_acknowledged(tmp_path):
    """A writer streams numbered batches; the server is SIGKILLed twice and restarted on
    the same port. The client resends what was not acknowledged; afterwards the table
    holds every acknowledged batch exactly once."""
    port = free_port()
    servers = [durable_server(tmp_path, port)]
    client = ReplayClient(servers[0].address, max_retries=12)
    acked: list[int] = []
    stop = threading.Event()
    errors: list[Exception] = []

    def write():
        try:
            i = 0
            while not stop.is_set():
                client.insert("log", scalar_batch(np.arange(i * 10, i * 10 + 10)))
                acked.append(i)
                i += 1
        except Exception as error:
            errors.append(error)

    writer = threading.Thread(target=write)
    writer.start()
    for _ in range(2):
        time.sleep(0.5)
        servers[-1].kill()
        time.sleep(0.2)
        servers.append(durable_server(tmp_path, port))
    time.sleep(0.5)
    stop.set()
    writer.join(60)
    assert not errors, errors
    assert len(acked) > 20
    stored = read_all(ReplayClient(servers[-1].address), "log")
    expected = np.concatenate([np.arange(i * 10, i * 10 + 10) for i in acked])
    np.testing.assert_array_equal(np.sort(stored), np.sort(expected))  # none lost, none doubled
    for server in servers:
        server.stop()


# ------------------------------------------------------------------ the sample count


def _table(folder, **spec) -> ReplayProcess:
    tables = [{"name": "t", "max_size": 10_000, "signature": SCALAR_SIGNATURE, **spec}]
    return ReplayProcess(tables, extra_args=["--checkpoint-dir", str(folder)])


def test_sigkill_keeps_the_count_of_samples_before_and_after_the_last_checkpoint(tmp_path):
    """7 batches sampled before a checkpoint, 5 after it, then SIGKILL: the restarted
    table counts all 12 (each was logged before it was sent), and every insert."""
    server = _table(tmp_path)
    client = ReplayClient(server.address)
    client.insert("t", scalar_batch(range(500)))
    for _ in range(7):
        client.sample("t", 32, timeout=5)
    client.checkpoint()
    for _ in range(5):
        client.sample("t", 32, timeout=5)
    client.insert("t", scalar_batch(range(500, 510)))
    server.kill()
    server.stop()
    with _table(tmp_path) as restarted:
        [table] = ReplayClient(restarted.address).info()
        assert (table.inserts, table.size, table.samples) == (510, 510, 12 * 32)


@pytest.mark.parametrize("checkpoint_after", [0, 3], ids=["log-only", "checkpoint-then-log"])
def test_the_samples_per_insert_ratio_holds_across_a_sigkill(tmp_path, checkpoint_after):
    """A learner that sampled all the ratio allows is not let ahead by a restart.

    samples_per_insert 1, min_size 10, error_buffer 40 and 110 items: a sample is admitted
    while samples <= 110 - 10 + 40 = 140, so 8 batches of 20 (160 items), not a 9th.
    """
    limiter = {"kind": "sample_to_insert_ratio", "samples_per_insert": 1.0, "min_size": 10,
               "error_buffer": 40.0}  # fmt: skip
    server = _table(tmp_path, rate_limiter=limiter)
    client = ReplayClient(server.address)
    client.insert("t", scalar_batch(range(110)))
    for i in range(8):
        if i == checkpoint_after and checkpoint_after:
            client.checkpoint()
        client.sample("t", 20, timeout=5)
    with pytest.raises(DeadlineExceeded):
        client.sample("t", 20, timeout=0.5)
    server.kill()
    server.stop()
    with _table(tmp_path, rate_limiter=limiter) as restarted:
        client = ReplayClient(restarted.address)
        assert client.info()[0].samples == 160
        with pytest.raises(DeadlineExceeded):
            client.sample("t", 20, timeout=0.5)  # as before the kill: the ratio is spent
        client.insert("t", scalar_batch(range(110, 130)))  # 20 more items admit one batch
        assert len(client.sample("t", 20, timeout=5)["x"]) == 20


def test_non_loopback_bind_without_token_is_refused_by_the_cli():
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "graft.cli.replay",
            "serve",
            "--host",
            "0.0.0.0",
            "--port",
            "0",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0
    assert "needs a shared token" in result.stderr


def test_sample_stream_reconnects_after_a_server_restart(tmp_path):
    port = free_port()
    first = durable_server(tmp_path, port)
    client = ReplayClient(first.address, max_retries=12)
    client.insert("log", scalar_batch(range(20)))
    stream = client.sample_stream("log", 5, prefetch=2)
    assert next(stream)["x"].shape == (5,)
    first.kill()
    second = durable_server(tmp_path, port)
    batches = [next(stream)["x"] for _ in range(6)]  # across the restart
    stream.close()
    assert all(b.shape == (5,) for b in batches)
    second.stop()


LAUNCHER = """
import sys, time
from graft.replay_host.process import ReplayProcess
table = [{"name": "log", "max_size": 100, "sampler": "fifo",
          "signature": {"x": {"dtype": "float32", "shape": []}}}]
server = ReplayProcess(table, extra_args=["--checkpoint-dir", sys.argv[1]])
print(server.process.pid, flush=True)
time.sleep(600)
"""


def test_server_stops_with_a_final_checkpoint_when_its_launcher_is_killed(tmp_path):
    launcher = subprocess.Popen(
        [sys.executable, "-c", LAUNCHER, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    server_pid = int(launcher.stdout.readline())
    launcher.kill()  # SIGKILL: the launcher cannot stop its child itself
    launcher.wait()
    deadline = time.monotonic() + 30.0
    while _alive(server_pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(server_pid), "the replay server outlived its killed launcher"
    assert len(list(tmp_path.glob("checkpoint-*.npz"))) == 1  # it stopped the graceful way


def _alive(pid: int) -> bool:
    """True while `pid` runs (a zombie counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False
