"""Benchmark: is a run reproducible? Trains one preset twice with the same seed and
compares the two metrics.csv files row by row.

In reproducible mode (`--reproducible`, the learner driving the actors in lock-step)
the files must be identical byte for byte: metrics.csv then holds no wall-clock column
(wall-clock rates go to timing.csv). With `--also-async` the same is done in the default
asynchronous mode, comparing every column but `wall_s` and skipping the `perf/` rows (the
wall-clock measurements), to show what the mode is for. Prints "identical", or the first
differing row of each file, and the wall time of each run.

    python bench/reproduce.py [--preset pendulum-td3] [--seed 0] [--env-steps 3000]
                              [--set key=value ...] [--also-async] [--out runs/bench-reproduce]
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path
from typing import Optional

import ray

from graft.cli.flags import parse_settings
from graft.config import load_preset
from graft.orchestration.launcher import train
from graft.orchestration.ray_session import connect_ray
from service.metrics import MetricsLogger


def comparable_rows(csv_path: Path) -> list[str]:
    """The rows of a metrics.csv a rerun must repeat: all of them in reproducible mode
    (no wall-clock column there); in the default mode every column but `wall_s`, and no
    `perf/` (wall-clock) row."""
    lines = csv_path.read_text().splitlines()
    if not lines[0].startswith("wall_s,"):
        return lines
    rows = [line.split(",", 1)[1] for line in lines]
    return [r for r in rows if not r.split(",")[2].startswith(MetricsLogger.TIMING_PREFIX)]


def first_difference(a: list[str], b: list[str]) -> Optional[tuple[int, str, str]]:
    """(row number, row of a, row of b) of the first row that differs, or None."""
    for i in range(max(len(a), len(b))):
        row_a = a[i] if i < len(a) else "(no row: file ends)"
        row_b = b[i] if i < len(b) else "(no row: file ends)"
        if row_a != row_b:
            return i, row_a, row_b
    return None


def run_twice(args: argparse.Namespace, *, reproducible: bool) -> None:
    mode = "reproducible" if reproducible else "asynchronous"
    overrides = {**parse_settings(args.set), "seed": args.seed, "env_steps": args.env_steps}
    config = load_preset(args.preset, reproducible=reproducible, **overrides)
    files, walls = [], []
    for k in (1, 2):
        run_dir = args.out / f"{mode}-{k}"
        shutil.rmtree(run_dir, ignore_errors=True)
        start = time.perf_counter()
        result = train(config, run_dir=run_dir, progress=False)
        walls.append(time.perf_counter() - start)
        files.append(result.run_dir / "metrics.csv")
        print(
            f"{mode} run {k}: {result.summary['updates']} updates, final evaluation "
            f"{result.summary['final_eval_return_mean']:.1f}, {walls[-1]:.0f} s",
            flush=True,
        )
    rows = [comparable_rows(f) for f in files]
    difference = first_difference(*rows)
    what = "" if reproducible else " (wall_s and perf/ rows left out)"
    print(f"{args.preset} seed {args.seed}, {mode} mode, metrics.csv of two runs{what}:")
    if difference is None:
        print(f"  identical ({len(rows[0]) - 1} rows)")
    else:
        i, a, b = difference
        print(f"  first differing row, {i} (of {len(rows[0]) - 1} and {len(rows[1]) - 1}):")
        print(f"    run 1: {a}\n    run 2: {b}")
    print(f"  wall time {walls[0]:.0f} s and {walls[1]:.0f} s", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="pendulum-td3")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--env-steps", type=int, default=3000)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--also-async", action="store_true", help="also the default mode")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-reproduce"))
    args = parser.parse_args()
    started = connect_ray("local")  # a Ray instance of its own
    try:
        run_twice(args, reproducible=True)
        if args.also_async:
            run_twice(args, reproducible=False)
    finally:
        if started:
            ray.shutdown()


if __name__ == "__main__":
    main()
