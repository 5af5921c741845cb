"""Benchmark: the CPU that world servers started together on a fresh install spend on the
frame's compiled kernels, with `render.warm_up`'s lock (one compiles, the others load its
cache) against each process compiling alone.

Each arm starts N processes at once, each importing the renderer and compiling its kernels,
over an empty numba cache of its own (NUMBA_CACHE_DIR): a fresh install, or a fresh
checkout. The arms alternate within one run, so another job on the machine moves both
alike; the ratio is the figure.

    python bench/render_compile.py [--processes 4] [--rounds 2]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from side_by_side import report  # bench/, beside this script

REPO = Path(__file__).resolve().parents[1]
ARMS = {
    "each compiles alone": "render.compile_kernels()",
    "behind the lock (warm_up)": "render.warm_up()",
}


def start_together(call: str, processes: int) -> tuple[float, float]:
    """CPU seconds of `processes` processes making `call` at once over an empty numba cache,
    and the wall seconds until the last one is done."""
    code = f"from minecraft.sim import render; {call}"
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache, "PYTHONPATH": str(REPO)}
        start = time.perf_counter()
        pids = [
            subprocess.Popen([sys.executable, "-c", code], env=env, cwd=REPO).pid
            for _ in range(processes)
        ]
        cpu = 0.0
        for pid in pids:
            _, status, usage = os.wait4(pid, 0)
            if status != 0:
                raise RuntimeError(f"a compiling process failed (wait status {status})")
            cpu += usage.ru_utime + usage.ru_stime
        return cpu, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--processes", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    figures: dict[str, list[tuple[float, float]]] = {arm: [] for arm in ARMS}
    for round_ in range(1, args.rounds + 1):
        for arm, call in ARMS.items():
            cpu, wall = start_together(call, args.processes)
            figures[arm].append((cpu, wall))
            print(f"round {round_}, {arm}: {cpu:.1f} s of CPU, {wall:.1f} s wall", flush=True)
    print(f"\n{args.processes} processes at once, empty cache, median of {args.rounds} rounds")
    report(figures, column="kernels", unit="", digits=1)


if __name__ == "__main__":
    main()
