"""A pytest plugin for finding where the suite's CPU goes: the CPU each test used, counting
every process it started (Ray's workers, servers, subprocesses), in a JSON line per test.

Each pytest process (each xdist worker; not xdist's controller) moves itself into a cgroup
of its own under ``/sys/fs/cgroup/cpuacct/$GRAFT_CPU_CGROUP`` (cgroup v1 ``cpuacct``;
root), which every process it starts inherits, and reads its ``cpuacct.usage`` around each
test. Timing a
whole run the usual way (``time make test``) misses Ray's workers: they are not the
timed process's children.

    mkdir -p /sys/fs/cgroup/cpuacct/suite
    GRAFT_CPU_CGROUP=suite GRAFT_CPU_REPORT=/tmp/cpu.jsonl PYTHONPATH=. \\
        .venv/bin/python -m pytest -p tests.tools.cpu_per_test -n 2 --dist loadfile ...
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Optional

import pytest

_group: Optional[Path] = None
_started: dict[str, tuple[float, float]] = {}


def pytest_configure(config: pytest.Config) -> None:
    global _group
    parent = Path("/sys/fs/cgroup/cpuacct") / os.environ.get("GRAFT_CPU_CGROUP", "suite")
    if config.getoption("dist", "no") != "no" and not hasattr(config, "workerinput"):
        # The xdist controller: its workers measure the tests (it would log each again).
        config.pluginmanager.unregister(sys.modules[__name__])
        return
    _group = parent / os.environ.get("PYTEST_XDIST_WORKER", f"main-{os.getpid()}")
    _group.mkdir(parents=True, exist_ok=True)
    (_group / "tasks").write_text(str(os.getpid()))


def _cpu_s() -> float:
    assert _group is not None
    return int((_group / "cpuacct.usage").read_text()) / 1e9


def pytest_runtest_logstart(nodeid: str, location: tuple[str, Optional[int], str]) -> None:
    _started[nodeid] = (_cpu_s(), time.monotonic())


def pytest_runtest_logfinish(nodeid: str, location: tuple[str, Optional[int], str]) -> None:
    cpu, wall = _started.pop(nodeid)
    row = {
        "id": nodeid,
        "cpu_s": round(_cpu_s() - cpu, 2),
        "wall_s": round(time.monotonic() - wall, 2),
        "group": _group.name,
    }
    with open(os.environ.get("GRAFT_CPU_REPORT", "cpu_per_test.jsonl"), "a") as out:
        out.write(json.dumps(row) + "\n")
