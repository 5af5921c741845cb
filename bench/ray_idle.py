"""Benchmark: the CPU an idle local Ray instance costs, as Ray starts it (without its
dashboard, as graft asks) and as graft starts it (`ray_session.start_local`: no log
monitor, no autoscaler monitor, no idle worker processes kept).

On a 2-core machine an instance's own processes (GCS, raylet, agents, idle workers) compete
with the actors and the learner for the whole run. Each round starts one instance of each
kind in turn, lets it settle, then sums the CPU its processes (every descendant of this
one) use over an idle window. The kinds alternate within one run, so another job on the
machine moves both alike; the ratio is the figure.

    python bench/ray_idle.py [--rounds 3] [--window-s 30]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import ray
from procfs import cpu_seconds  # bench/, beside this script

from graft.orchestration.ray_session import start_local

import psutil  # isort: skip  (Ray's vendored copy: importable once Ray is imported)


def ray_default() -> None:
    ray.init(
        address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
        configure_logging=False,
    )  # fmt: skip


def graft_local() -> None:
    start_local(num_cpus=2)


KINDS: dict[str, Callable[[], None]] = {"Ray, no dashboard": ray_default, "graft": graft_local}
SETTLE_S = 5.0
"""Seconds after the start before the window opens (start-up is not idle cost)."""


def descendants_cpu_s() -> float:
    """CPU seconds (user + system) so far of every live process this one started."""
    total = 0.0
    for child in psutil.Process().children(recursive=True):
        try:
            total += cpu_seconds(child.pid)
        except OSError:  # ended since it was listed
            continue
    return total


def idle_cpu_per_min(start: Callable[[], None], window_s: float) -> float:
    """CPU seconds per minute the instance's processes use while nothing runs on it."""
    start()
    try:
        time.sleep(SETTLE_S)
        before = descendants_cpu_s()
        time.sleep(window_s)
        return (descendants_cpu_s() - before) * 60.0 / window_s
    finally:
        ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--window-s", type=float, default=30.0)
    args = parser.parse_args()
    rates: dict[str, list[float]] = {kind: [] for kind in KINDS}
    for round_ in range(1, args.rounds + 1):
        for kind, start in KINDS.items():
            rate = idle_cpu_per_min(start, args.window_s)
            rates[kind].append(rate)
            print(f"round {round_}, {kind}: {rate:.2f} s of CPU per idle minute", flush=True)
    print("\n| local instance | CPU per idle minute, median | share of one core |")
    print("|---|---|---|")
    for kind, values in rates.items():
        median = statistics.median(values)
        print(f"| {kind} | {median:.2f} s | {median / 60:.1%} |")
    default, lean = (statistics.median(rates[k]) for k in KINDS)
    print(f"\ngraft / Ray, idle CPU: {lean / default:.2f}")


if __name__ == "__main__":
    main()
