"""Replay shards in a run (`replay.shards`): each shard's share of the table, refused
shard counts, and a tiny run on two real replay servers that survives one's SIGKILL."""

from __future__ import annotations

import contextlib
import csv
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from graft.config import load_preset
from graft.orchestration.launcher import train
from graft.replay_host.process import ReplayProcess
from graft.replay_host.shards import shard_tables
from graft.validation import ConfigError
from service.replay.errors import DeadlineExceeded
from service.replay.sharding import ShardedReplayClient
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch

TABLE = {
    "name": "transitions",
    "max_size": 1000,
    "signature": {},
    "seed": 7,
    "rate_limiter": {
        "kind": "sample_to_insert_ratio", "samples_per_insert": 256.0, "min_size": 1000,
        "error_buffer": 51200.0, "sample_credit": 300.0,
    },
}  # fmt: skip


def test_one_shard_is_the_run_table_unchanged() -> None:
    assert shard_tables([TABLE], 1) == [[TABLE]]


def test_shards_split_size_minimum_buffer_and_credit_so_the_sums_hold() -> None:
    shards = [tables[0] for tables in shard_tables([TABLE], 3)]
    limiters = [s["rate_limiter"] for s in shards]
    assert [s["max_size"] for s in shards] == [334, 334, 334]
    assert [r["min_size"] for r in limiters] == [334, 333, 333]  # sums to 1000
    assert [r["error_buffer"] for r in limiters] == pytest.approx([51200 / 3] * 3)
    assert [r["sample_credit"] for r in limiters] == pytest.approx([100.0] * 3)
    assert {r["samples_per_insert"] for r in limiters} == {256.0}  # the ratio is the preset's
    assert len({s["seed"] for s in shards}) == 3  # each shard samples with its own seed
    assert TABLE["rate_limiter"]["min_size"] == 1000  # the run's table is left as it was


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"replay.shards": 0}, "replay.shards=0 must lie in [1, 255]"),
        ({"replay.shards": 3}, "replay.shards=3 needs num_actors >= 3"),
        ({"replay.shards": 2, "slack_env_steps": 1}, "replay.shards=2 needs slack_env_steps >= 2"),
        ({"replay.shards": 2, "reproducible": True}, "replay.shards=2: a reproducible run"),
        ({"replay.shards": 2, "replay.port": 65535}, "replay.port=65535 with shards=2"),
    ],
)
def test_a_shard_count_the_run_cannot_use_is_one_line(overrides, message) -> None:
    with pytest.raises(ConfigError) as caught:
        load_preset("pendulum-td3", **overrides)
    assert str(caught.value).startswith(message) and "\n" not in str(caught.value)


@pytest.mark.service
def test_two_shards_hold_the_ratio_over_the_whole_replay() -> None:
    # 4 samples per inserted item over two real shards, the learner slower than the
    # writers (so both limiters hold inserts at the top of their buffers): each limiter
    # holds its share, so the sums hold the one server's balance, not twice its buffer.
    spi, min_size, buffer = 4.0, 20, 160.0
    run_table = {
        "name": "t", "max_size": 10_000, "signature": SCALAR_SIGNATURE,
        "rate_limiter": {"kind": "sample_to_insert_ratio", "samples_per_insert": spi,
                         "min_size": min_size, "error_buffer": buffer},
    }  # fmt: skip
    with contextlib.ExitStack() as stack:
        servers = [
            stack.enter_context(ReplayProcess(tables)) for tables in shard_tables([run_table], 2)
        ]
        addresses = [s.address for s in servers]
        stop = threading.Event()

        def write(home: int, pause_s: float) -> None:
            client, start = ShardedReplayClient(addresses, home=home), 0
            while not stop.is_set():
                try:
                    client.insert("t", scalar_batch(np.arange(start, start + 4)), timeout=0.2)
                    start += 4
                except DeadlineExceeded:
                    pass  # held by its shard's limiter
                time.sleep(pause_s)

        writers = [threading.Thread(target=write, args=(k, 0.001)) for k in (0, 1)]
        for w in writers:
            w.start()
        stream = ShardedReplayClient(addresses, seed=0).sample_stream("t", 8, prefetch=2)
        try:
            for _ in range(150):
                stream.next_within(10.0)
                time.sleep(0.005)  # the learner's update
        finally:
            stream.close()
            stop.set()
            for w in writers:
                w.join()
        status = [ShardedReplayClient(addresses).info()[k][0] for k in (0, 1)]
    assert min(s.inserts for s in status) > min_size  # both writers got past their share
    inserts, samples = sum(s.inserts for s in status), sum(s.samples for s in status)
    assert samples >= 150 * 8
    imbalance = inserts * spi - samples - min_size * spi
    # Within the preset's buffer, but for each shard's overshoot by one batch.
    assert -buffer - 2 * 8 <= imbalance <= buffer + 2 * 4 * spi, (inserts, samples)


def _own_shard_server(run_dir: Path, shard: int) -> int:
    """The PID of this process's replay server for `shard` of the run in `run_dir`: its
    child, or its fork server's."""
    folder = str(run_dir / "replay" / f"shard-{shard}")
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text()
            parents[int(entry.name)] = int(stat.rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    for pid, ppid in parents.items():
        if os.getpid() not in (ppid, parents.get(ppid)):
            continue
        try:
            command = (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ")
        except OSError:
            continue
        if b"graft.cli.replay serve" in command and folder.encode() in command:
            return pid
    raise AssertionError(f"no replay server of {folder} among this process's children")


def _metric(path: Path, key: str) -> list[float]:
    with path.open() as f:
        return [float(row["value"]) for row in csv.DictReader(f) if row["key"] == key]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_run_on_two_shards_fills_both_and_survives_a_killed_shard(
    ray_local, tmp_path, capsys
) -> None:
    env_steps, learning_starts = 1200, 200
    config = load_preset(
        "pendulum-td3",
        env_steps=env_steps,
        learning_starts=learning_starts,
        eval_every=100_000,
        eval_episodes=1,
        publish_every=20,
        checkpoint_every=500,
        num_actors=2,
        envs_per_actor=2,
        steps_per_insert=4,
        # Samples are not logged: a restarted shard forgets those since its checkpoint
        # (1 s here), and its limiter then holds its writer's last inserts by as many
        # items; a slack of 200 items per shard absorbs most of that.
        slack_env_steps=400,
        **{"replay.shards": 2, "replay.checkpoint_every_s": 1.0},
        **{"td3.hidden_sizes": [32, 32], "td3.batch_size": 32},
    )
    outcome: dict[str, object] = {}

    def run() -> None:
        try:
            outcome["result"] = train(config, run_dir=tmp_path, progress=False)
        except BaseException as error:  # raised below, on the test's thread
            outcome["error"] = error

    runner = threading.Thread(target=run)
    runner.start()
    metrics = tmp_path / "metrics.csv"
    deadline = time.monotonic() + 300
    # The fault strikes once the learner trains (its first metrics rows are written).
    while not (metrics.exists() and len(metrics.read_text().splitlines()) > 4):
        assert runner.is_alive(), outcome
        assert time.monotonic() < deadline, "the run did not start training"
        time.sleep(0.2)
    os.kill(_own_shard_server(tmp_path, 1), signal.SIGKILL)
    runner.join(timeout=max(deadline - time.monotonic(), 1))
    assert not runner.is_alive(), "the run did not finish"
    if "error" in outcome:
        raise outcome["error"]  # type: ignore[misc]

    summary = outcome["result"].summary  # type: ignore[attr-defined]
    assert summary["updates"] == env_steps - learning_starts  # the learner's whole budget
    # An actor whose last inserts the restarted shard still holds when the learner is done
    # is stopped with what it stored (deploy/README.md, Faults): at most a few batches.
    assert sum(summary["actor_env_steps"]) >= env_steps - 100, summary["actor_env_steps"]
    inserts = summary["replay_shard_inserts"]
    assert len(inserts) == 2 and min(inserts) > 0, inserts  # every shard got inserts
    err = capsys.readouterr().err
    assert "shard 1: replay server died (exit code -9); restarted" in err, err
    assert _metric(metrics, "faults/replay_restarts")[-1] == 1
    for k in (0, 1):  # each shard kept its own checkpoint folder and log
        assert (tmp_path / "replay" / f"shard-{k}").is_dir()
        assert (tmp_path / f"replay-shard-{k}.log").stat().st_size > 0
