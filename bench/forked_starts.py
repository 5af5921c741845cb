"""Benchmark: replay and world servers started as forks of a fork server
(`service.forkserver`) against plain child processes, many starts by one driver, as a
sweep, a supervisor's restarts and the test suite make them.

Each round, in each mode in turn, one driver starts `--starts` servers of each kind one
after another (`ReplayProcess`, `ServerPool`), each until it answers, and stops it. The
CPU is each server's own (user + system) until it answered, plus, for the forks, their fork
server's whole life (its start, once per round and kind, included). The modes alternate,
so another job on the machine moves both alike; the ratio is the figure.

    python bench/forked_starts.py [--starts 10] [--rounds 2]
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.compiled_starts import compare, parse_rounds  # noqa: E402
from bench.procfs import cpu_seconds  # noqa: E402
from graft.replay_host.process import ReplayProcess  # noqa: E402
from minecraft.sim.pool import ServerPool  # noqa: E402
from service import forkserver  # noqa: E402

TABLE = [{"name": "t", "max_size": 100, "signature": {"x": {"dtype": "int64", "shape": []}}}]
MODES = {"plain processes": False, "forks": True}


def replay_server() -> float:
    with ReplayProcess(TABLE) as server:
        return _cpu_with_parent(server.process)


def world_server() -> float:
    with ServerPool(1, seed=0) as pool:
        return _cpu_with_parent(pool.procs[0])


_fork_servers: set[int] = set()


def _cpu_with_parent(process: forkserver.Process) -> float:
    """The process's CPU so far; its fork server's is added once, at the round's end."""
    if isinstance(process, forkserver.ForkedProcess):
        with open(f"/proc/{process.pid}/stat") as f:
            _fork_servers.add(int(f.read().rsplit(")", 1)[1].split()[1]))
    return cpu_seconds(process.pid)


def round_cost(start: Callable[[], float], starts: int) -> float:
    """CPU seconds a start costs, on average over `starts`, the fork server included."""
    total = sum(start() for _ in range(starts))
    total += sum(cpu_seconds(pid) for pid in _fork_servers)
    forkserver.close_all()
    _fork_servers.clear()
    return total / starts


def main() -> None:
    args = parse_rounds(argparse.ArgumentParser(description=__doc__.split("\n")[0]))
    kinds = {"replay server": replay_server, "world server": world_server}

    def cost(kind: str, mode: str) -> float:
        forkserver.ENABLED = MODES[mode]
        return round_cost(kinds[kind], args.starts)

    compare(
        list(kinds), list(MODES), cost, rounds=args.rounds,
        heading=f"process ({args.starts} starts, CPU a start)",
    )  # fmt: skip


if __name__ == "__main__":
    main()
