"""Run the obtain-diamond behaviour tree on seeded worlds and print a markdown table.

Each world is a real simulated world server (in the worker process, real Malmo's timing)
driven by graft's MalmoEnv client in MineRL's synchronous mode, with the sample
obtain-diamond mission (20 in-game minutes = 24,000 ticks; the small frame, as the tree
reads observations only).

    python bench/diamond.py [--worlds 20] [--first-seed 0] [--procs 2]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from actors.minecraft.agent.diamond_tree import EpisodeResult, run_episode  # noqa: E402
from actors.minecraft.malmo.client import MalmoClient  # noqa: E402
from actors.minecraft.malmo.mission_xml import obtain_diamond  # noqa: E402
from actors.minecraft.sim.server import WorldServer  # noqa: E402

TIME_LIMIT_TICKS = 24_000


def _mission(seed: int) -> str:
    # The tree reads observations only: the small frame real Malmo needs, no 64x64 one.
    return obtain_diamond(seed=seed, pixels=False)


def run_world(seed: int) -> tuple[EpisodeResult, float]:
    """One world: a server on a free port, the tree through the client."""
    t0 = time.perf_counter()
    with WorldServer(port=0, seed=seed) as server:
        client = MalmoClient("127.0.0.1", server.port, synchronous=True, seed=seed)
        client.init(_mission(seed))
        try:
            result = run_episode(client, seed=seed, max_ticks=TIME_LIMIT_TICKS + 5)
        finally:
            client.close()
    return result, time.perf_counter() - t0


def _clock(ticks: int) -> str:
    s = ticks // 20
    return f"{s // 60}:{s % 60:02d}"


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=20, help="number of seeded worlds")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first world")
    ap.add_argument("--procs", type=int, default=2, help="worlds run in parallel")
    args = ap.parse_args(argv)
    seeds = list(range(args.first_seed, args.first_seed + args.worlds))
    t0 = time.perf_counter()
    results: list[tuple[EpisodeResult, float]] = []
    with mp.get_context("spawn").Pool(args.procs) as pool:
        for r, secs in pool.imap_unordered(run_world, seeds, chunksize=1):
            results.append((r, secs))
            print(f"[{len(results)}/{len(seeds)}] seed {r.seed}: {r.stage}, "
                  f"{r.ticks} ticks, {secs:.0f} s", file=sys.stderr, flush=True)  # fmt: skip
    results.sort(key=lambda rs: rs[0].seed)
    wall = time.perf_counter() - t0
    print("| world seed | diamond | stage reached | in-game time (m:ss) | ticks | deaths | "
          "iron pickaxe at | wall s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for r, secs in results:
        iron = r.reached.get("iron_pickaxe")
        print(
            f"| {r.seed} | {'yes' if r.diamond else 'no'} | {r.stage} | {_clock(r.ticks)} | "
            f"{r.ticks} | {r.deaths} | {_clock(iron) if iron is not None else '-'} | "
            f"{secs:.0f} |"
        )
    got = [r for r, _ in results if r.diamond]
    print()
    print(f"diamonds: {len(got)}/{len(results)} worlds; deaths: "
          f"{sum(r.deaths for r, _ in results)}; median time to diamond: "
          f"{_clock(int(statistics.median(r.ticks for r in got))) if got else '-'}; "
          f"wall {wall:.0f} s with {args.procs} processes")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
