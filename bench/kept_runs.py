"""Benchmark: tiny runs back to back in one driver on a Ray instance it keeps up, with the
weight broadcaster, the evaluator and the environment actors handed from run to run
(graft/orchestration/kept.py) against all started anew for each run.

Each round trains `--runs` tiny pendulum-td3 runs (300 env steps, `--actors` actors) in
each mode in turn, so another job on the machine moves both alike. A run's CPU is every process's:
this driver's, and that of every process it started (Ray's daemons and workers, the
replay servers), ended ones included. The first run of each mode is left out: it finds
what the mode before kept, or nothing. The ratio is the figure.

    python bench/kept_runs.py [--runs 5] [--rounds 2] [--actors 2]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import ray
from side_by_side import report  # bench/, beside this script

from graft.config import load_preset
from graft.orchestration.kept import KEEP_S, KEPT
from graft.orchestration.launcher import train
from graft.orchestration.ray_session import start_local

TINY = {
    "env_steps": 300,
    "learning_starts": 100,
    "eval_every": 200,
    "eval_episodes": 1,
    "publish_every": 20,
    "envs_per_actor": 2,
    "td3.hidden_sizes": [32, 32],
}
CGROUP = Path("/sys/fs/cgroup/cpuacct") / "graft-bench"
"""The benchmark's cgroup: kept for the next run (only differences of its count are read)."""
MODES = {"started anew": 0.0, "handed on": KEEP_S}
"""How long a finished run's helpers are kept, by mode (0: ended at once)."""


def all_cpu_s() -> float:
    """CPU seconds of this process and of every process started since `account_all`,
    ended ones included: its cgroup's (Ray's workers are not this process's children,
    and Ray's daemons reap their workers unaccounted)."""
    return int((CGROUP / "cpuacct.usage").read_text()) / 1e9


def account_all() -> None:
    """Moves this process into the benchmark's cgroup (cgroup v1 ``cpuacct``; as root),
    which every process it starts from now on inherits."""
    try:
        CGROUP.mkdir(parents=True, exist_ok=True)
        (CGROUP / "tasks").write_text(str(os.getpid()))
    except OSError as error:
        raise SystemExit(
            f"bench/kept_runs.py: cannot account in {CGROUP} ({error}): "
            "run as root, on cgroup v1's cpuacct"
        ) from None


def round_of_runs(runs: int, actors: int, folder: Path) -> tuple[float, float]:
    """CPU and wall seconds per run, the first run left out."""
    config = load_preset("pendulum-td3", **{**TINY, "num_actors": actors})
    train(config, run_dir=folder / "first", progress=False)
    cpu, wall = all_cpu_s(), time.perf_counter()
    for i in range(runs - 1):
        train(config, run_dir=folder / f"run{i}", progress=False)
    return (all_cpu_s() - cpu) / (runs - 1), (time.perf_counter() - wall) / (runs - 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="runs per mode and round (>= 2)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--actors", type=int, default=2, help="environment actors a run")
    args = parser.parse_args()
    if args.runs < 2 or args.rounds < 1 or args.actors < 1:
        parser.error("--runs must be >= 2, --rounds and --actors >= 1")
    account_all()
    start_local(num_cpus=2)
    figures: dict[str, list[tuple[float, float]]] = {mode: [] for mode in MODES}
    with tempfile.TemporaryDirectory() as tmp:
        for round_ in range(1, args.rounds + 1):
            for mode, keep_s in MODES.items():
                KEPT.keep_s = keep_s
                cpu, wall = round_of_runs(args.runs, args.actors, Path(tmp) / f"{round_}-{keep_s}")
                figures[mode].append((cpu, wall))
                print(f"round {round_}, {mode}: {cpu:.2f} s of CPU, {wall:.2f} s a run", flush=True)
    ray.shutdown()
    print()
    report(figures, column="helpers", unit=" a run", digits=2)


if __name__ == "__main__":
    main()
