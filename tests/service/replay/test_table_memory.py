"""Memory bounds of the replay server: each table's worst-case bytes against the budget
(cgroup limit, else machine memory, less a margin; or --max-memory), refused at start in
one line; a table's max_bytes; bytes used against the budget in `graft replay info` and
the metrics."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest

from graft.replay_host.process import ReplayProcess
from service.memory import MemoryBudget, cgroup_limit, memory_budget
from service.replay.client import ReplayClient
from service.replay.server.signature import Signature
from service.replay.server.table_config import make_table, make_tables
from service.replay.server.table_memory import item_bytes, table_bytes
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, scalar_batch

FRAMES = {"obs": {"dtype": "uint8", "shape": [84, 84, 3]}, "reward": {"dtype": "float32"}}
"""An Atari-sized frame per item: 21,176 bytes a record."""


def _serve(
    tables: list[dict], *args: str, cgroup: Path | None = None
) -> subprocess.CompletedProcess:
    """`graft replay serve` run to its end (refused at start), optionally in `cgroup`."""
    folder = Path(os.environ.get("TMPDIR", "/tmp"))
    config = folder / f"graft-memory-{os.getpid()}.json"
    config.write_text(json.dumps({"tables": tables}))
    command = [sys.executable, "-m", "graft.cli", "replay", "serve", "--config"]
    command += [str(config), "--port", "0", *args]
    if cgroup is not None:  # the child joins the cgroup before it starts Python
        command = ["sh", "-c", f'echo $$ > {cgroup}/cgroup.procs && exec "$@"', "sh", *command]
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=120)
    finally:
        config.unlink()


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_a_table_larger_than_the_machine_is_refused_in_one_line() -> None:
    # numpy's _ArrayMemoryError traceback before: 394 GiB asked for at once.
    done = _serve([{"name": "frames", "max_size": 20_000_000, "signature": FRAMES}])
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(
        "graft replay serve: table 'frames' needs 394.4 GiB at max_size 20000000 (21176 B an "
        "item), over the memory budget "
    )
    assert str(memory_budget()) in lines[0]


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_max_memory_bounds_the_tables_together_and_max_bytes_caps_one() -> None:
    tables = [
        {"name": "a", "max_size": 1000, "signature": FRAMES},  # 20.2 MiB
        {"name": "b", "max_size": 1000, "signature": FRAMES},
    ]
    done = _serve(tables, "--max-memory", "30M")
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        "graft replay serve: table 'b' needs 20.2 MiB at max_size 1000 (21176 B an item) with "
        "20.2 MiB of tables before it, over the memory budget 30.0 MiB (--max-memory 30.0 "
        "MiB); lower max_size, give the table a max_bytes, or set --max-memory"
    ]
    capped = [tables[0], {**tables[1], "max_bytes": 5 * 2**20}]
    port = free_port()
    with ReplayProcess(
        capped, extra_args=["--max-memory", "30M", "--metrics-port", str(port)]
    ) as s:
        client = ReplayClient(s.address)
        b = next(t for t in client.info() if t.name == "b")
        assert b.max_size == 5 * 2**20 // 21176  # the remover evicts past 247 items
        assert b.memory_budget_bytes == 30 * 2**20 and b.memory_budget == "--max-memory 30.0 MiB"
        shown = subprocess.run(
            [sys.executable, "-m", "graft.cli", "replay", "info", s.address],
            capture_output=True, text=True, timeout=60, check=True,
        ).stdout  # fmt: skip
        assert "memory: tables 0 B used, 25.2 MiB at max_size, of a budget of 30.0 MiB" in shown
        metrics = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read()
        assert b"graft_replay_memory_budget_bytes 3.145728e+07" in metrics
        assert b'graft_replay_table_bytes_used{table="a"} 0.0' in metrics


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_bytes_used_grow_with_the_items_stored() -> None:
    with ReplayProcess([{"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE}]) as s:
        client = ReplayClient(s.address)
        client.insert("t", scalar_batch(range(25)))
        (t,) = client.info()
        assert t.bytes_used * 4 == t.bytes_in_memory  # a quarter full
        assert t.memory_budget_bytes == memory_budget().bytes


@pytest.mark.parametrize(
    "spec",
    [
        {"max_size": 1000},
        {"max_size": 999, "max_sequence_length": 4},
        {"max_size": 10, "remover": "lifo"},
        {"max_size": 64, "max_times_sampled": 2, "max_sequence_length": 2},
    ],
)
def test_the_worst_case_is_what_the_table_allocates(spec: dict) -> None:
    table = make_table({"name": "t", "signature": FRAMES, **spec})
    per_item = item_bytes(
        Signature.from_dict(FRAMES),
        max_times_sampled=spec.get("max_times_sampled", 0),
        max_sequence_length=spec.get("max_sequence_length", 1),
        remover=spec.get("remover", "fifo"),
    )
    worst = table_bytes(spec["max_size"], per_item, prioritized=False)
    # Free-list tables hold Python objects per item too, which the arrays do not show.
    assert table.bytes_in_memory <= worst <= table.bytes_in_memory + 160 * spec["max_size"]


def test_make_tables_refuses_before_allocating() -> None:
    budget = MemoryBudget(2**20, "a test budget")
    with pytest.raises(ValueError, match=r"^table 'big' needs 202.0 MiB at max_size 10000"):
        make_tables([{"name": "big", "max_size": 10_000, "signature": FRAMES}], budget=budget)
    with pytest.raises(ValueError, match=r"max_bytes=100 holds no item: one takes 21176 B"):
        make_tables(
            [{"name": "t", "max_size": 9, "signature": FRAMES, "max_bytes": 100}], budget=budget
        )


def _cgroup(limit: int) -> Path:
    """A new memory cgroup (v1 or v2) with `limit`. Skipped only for a user who is not root
    (who may not make one); as root, a cgroup that cannot be made fails the test."""
    if os.geteuid() != 0:
        pytest.skip("making a memory cgroup needs root")
    for root, name in ((Path("/sys/fs/cgroup/memory"), "memory.limit_in_bytes"),
                       (Path("/sys/fs/cgroup"), "memory.max")):  # fmt: skip
        folder = root / f"graft-test-{os.getpid()}"
        try:
            folder.mkdir()
        except OSError:
            continue
        try:
            (folder / name).write_text(str(limit))
            return folder
        except OSError:
            folder.rmdir()
    raise AssertionError("root could not make a memory cgroup (v1 or v2) under /sys/fs/cgroup")


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_a_table_larger_than_the_cgroup_limit_is_refused_naming_it() -> None:
    # The red team's case: 200,000 frames (4.2 GB) in a 1.5 GiB cgroup were accepted, and
    # the kernel killed the server at 72,128 items.
    cgroup = _cgroup(3 * 2**29)
    try:
        done = _serve([{"name": "frames", "max_size": 200_000, "signature": FRAMES}], cgroup=cgroup)
    finally:
        cgroup.rmdir()
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        "graft replay serve: table 'frames' needs 3.9 GiB at max_size 200000 (21176 B an "
        "item), over the memory budget 1.2 GiB (the cgroup memory limit 1.5 GiB less 256.0 "
        "MiB); lower max_size, give the table a max_bytes, or set --max-memory"
    ]
    assert cgroup_limit() != 3 * 2**29  # this process stayed outside it
