"""Benchmark: what a process the tests start costs with graft's modules byte-compiled
against compiled from source, as every process compiles them where PYTHONDONTWRITEBYTECODE
is set and no ``__pycache__`` exists (a fresh checkout on the 2-core machine).

Two kinds of process, each started `--starts` times per round in both modes in turn (so
another job on the machine moves both alike): a replay server serving until its gRPC
port answers, and a Ray worker's imports (Ray, then the environment actor's module). Each
start is a fresh interpreter with PYTHONDONTWRITEBYTECODE=1, so nothing it compiles is
kept; the byte-compiled mode runs ``compileall`` first (into a copy of the tree: the
checkout is left as it is). CPU is the children's (user + system). The ratio is the figure.

    python bench/compiled_starts.py [--starts 10] [--rounds 2]
"""

from __future__ import annotations

import argparse
import compileall
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("graft", "service", "actors", "learner")
SERVE = (
    "from graft.replay_host.process import ReplayProcess; "
    "obs = {'dtype': 'float32', 'shape': [3]}; "
    "ReplayProcess([{'name': 't', 'max_size': 100, 'signature': {'obs': obs}}]).stop()"
)
KINDS = {
    "replay server (started until it answers)": SERVE,
    "Ray worker's imports (ray, actors.env_actor)": "import ray, actors.env_actor",
}


def children_cpu_s() -> float:
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    return used.ru_utime + used.ru_stime


def start_cost(tree: Path, code: str, starts: int) -> float:
    """CPU seconds per start of ``python -c code`` in `tree` (its processes included)."""
    env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1", "PYTHONPATH": str(tree)}
    before = children_cpu_s()
    for _ in range(starts):
        subprocess.run([sys.executable, "-c", code], cwd=tree, env=env, check=True)
    return (children_cpu_s() - before) / starts


def compare_starts(
    trees: dict[str, Path], kinds: dict[str, str], *, starts: int, rounds: int
) -> None:
    """Each kind's start cost (``python -c code``) in each of two trees, in turn, round
    after round; then the table `compare` prints, headed by the trees' names."""
    compare(
        list(kinds), list(trees), lambda kind, tree: start_cost(trees[tree], kinds[kind], starts),
        rounds=rounds,
    )  # fmt: skip


def compare(
    kinds: Sequence[str],
    modes: Sequence[str],
    cost: Callable[[str, str], float],
    *,
    rounds: int,
    heading: str = "process",
) -> None:
    """`cost(kind, mode)`, CPU seconds, for each kind in each of two modes in turn, round
    after round, so another job on the machine moves both alike; then each one's median
    and the second mode's against the first's, as a table."""
    costs: dict[str, dict[str, list[float]]] = {k: {m: [] for m in modes} for k in kinds}
    for round_ in range(1, rounds + 1):
        for kind in kinds:
            for mode in modes:
                spent = cost(kind, mode)
                costs[kind][mode].append(spent)
                print(f"round {round_}, {kind}, {mode}: {spent:.3f} s of CPU", flush=True)
    first, second = modes
    print(f"\n| {heading} | {first} | {second} | {second} / {first} |")
    print("|---|---|---|---|")
    for kind, by_mode in costs.items():
        a, b = (statistics.median(by_mode[m]) for m in (first, second))
        print(f"| {kind} | {a:.3f} s | {b:.3f} s | {b / a:.2f} |")


def parse_rounds(parser: argparse.ArgumentParser) -> argparse.Namespace:
    """`parser`'s arguments with ``--starts`` and ``--rounds`` (each at least 1) added."""
    parser.add_argument("--starts", type=int, default=10, help="starts per kind, tree and round")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    if args.starts < 1 or args.rounds < 1:
        parser.error("--starts and --rounds must be >= 1")
    return args


def copy_tree(to: Path) -> Path:
    """graft's packages, without any ``__pycache__``."""
    for name in PACKAGES:
        shutil.copytree(ROOT / name, to / name, ignore=shutil.ignore_patterns("__pycache__"))
    return to


def main() -> None:
    args = parse_rounds(argparse.ArgumentParser(description=__doc__.split("\n")[0]))
    with tempfile.TemporaryDirectory() as tmp:
        source, compiled = copy_tree(Path(tmp) / "source"), copy_tree(Path(tmp) / "compiled")
        for name in PACKAGES:
            compileall.compile_dir(compiled / name, quiet=1, workers=0)
        compare_starts(
            {"from source": source, "byte-compiled": compiled},
            KINDS,
            starts=args.starts,
            rounds=args.rounds,
        )


if __name__ == "__main__":
    main()
