"""Benchmark: the travel planner's compiled A* search (`minecraft/agent/astar.py`)
against the search of an earlier revision (by default ba29239, the last in Python), on the
searches the diamond tree makes in real worlds.

The tree plays each world seed for `--ticks` game ticks (bench/diamond.py's worlds, a
world server on a free port), every search it makes recorded. Each round then plans every
recorded search again with both searches in turn, and checks that they make the same plan
(steps, cost, expansions). The figure is the ratio of their times, side by side in one
process; searches that spend their whole budget (a goal out of reach) are shown apart.

    python bench/astar_search.py [--seeds 1 2 3] [--ticks 3000] [--against ba29239] [--rounds 2]
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from bench import diamond  # noqa: E402
from minecraft.agent import astar  # noqa: E402

Search = tuple  # (grid, start, goals, max_expansions, the plan made in the world)


def revision(rev: str) -> ModuleType:
    """`astar.py` as it was at git revision `rev`, imported as a module of its own."""
    source = subprocess.run(
        ["git", "show", f"{rev}:minecraft/agent/astar.py"],
        cwd=REPO, capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    path = Path(tempfile.mkdtemp()) / "astar_then.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("astar_then", path)
    assert spec is not None and spec.loader is not None
    module = sys.modules["astar_then"] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def record(seeds: list[int], ticks: int) -> list[Search]:
    """Every search the tree makes in these worlds (compiled planner), with its plan."""
    searches: list[Search] = []
    planned = astar.plan

    def recording(grid, start, goals, **kwargs):
        result = planned(grid, start, goals, **kwargs)
        searches.append((grid.copy(), start, frozenset(goals), kwargs["max_expansions"], result))
        return result

    astar.plan = recording
    try:
        for seed in seeds:
            t0 = time.process_time()
            before = len(searches)
            result, wall, _ = diamond.run_world(seed, max_ticks=ticks)
            print(
                f"world {seed}: {result.ticks} ticks, {len(searches) - before} searches, "
                f"{time.process_time() - t0:.1f} s of CPU (the tree and its world server)",
                flush=True,
            )
    finally:
        astar.plan = planned
    return searches


def _key(p) -> tuple:
    """A plan as plain values (each module has its own Step class)."""
    return [(s.kind, s.cell) for s in p.steps], p.cost, p.reached, p.expanded


def replan(module: ModuleType, searches: list[Search]) -> tuple[float, float]:
    """Seconds to plan every search again (those that spent their budget, all), checking
    each plan is the one made in the world."""
    spent = every = 0.0
    for grid, start, goals, budget, made in searches:
        t0 = time.perf_counter()
        p = module.plan(grid, start, goals, max_expansions=budget)
        dt = time.perf_counter() - t0
        if _key(p) != _key(made):
            raise SystemExit(
                f"{module.__name__} planned {p} where the world's search planned {made}"
            )
        every += dt
        spent += dt if not made.reached else 0.0
    return spent, every


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--ticks", type=int, default=3000)
    parser.add_argument("--against", default="ba29239", help="git revision of the baseline")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    then = revision(args.against)
    searches = record(args.seeds, args.ticks)
    exhausted = sum(not s[4].reached for s in searches)
    modules = {f"Python ({args.against})": then, "compiled": astar}
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in modules}
    for _ in range(args.rounds):
        for name, module in modules.items():
            times[name].append(replan(module, searches))
    print(f"\n{len(searches)} searches, {exhausted} of them spent their whole budget; "
          "every plan the same in both\n")  # fmt: skip
    print("| search | all searches, s | per search out of reach, ms |\n|---|---|---|")
    for name, rounds in times.items():
        every, spent = min(r[1] for r in rounds), min(r[0] for r in rounds)
        print(f"| {name} | {every:.2f} | {1e3 * spent / max(exhausted, 1):.1f} |")
    python, compiled = (min(r[1] for r in rounds) for rounds in times.values())
    print(f"\ncompiled / Python: {compiled / python:.3f} (best of {args.rounds} rounds each)")


if __name__ == "__main__":
    main()
