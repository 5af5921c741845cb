"""Run the obtain-diamond behaviour tree on seeded worlds and print markdown tables:
the outcome per world, then where the in-game time went (per activity, sub-tree and
leaf, and the dithering signs), with a PNG of the time per world by activity.

Each world is a real simulated world server (in the worker process, real Malmo's timing)
driven by graft's MalmoEnv client in MineRL's synchronous mode, with the sample
obtain-diamond mission (20 in-game minutes = 24,000 ticks; the small frame, as the tree
reads observations only).

    python bench/diamond.py [--worlds 20] [--first-seed 0] [--procs 2]
        [--png diamond_time.png] [--max-ticks 24000] [--ticks-per-step 1]
        [--controller RUN_DIR ...] [--travel-while ACTIVITY ...] [--diamond-keep 0.25]

``--ticks-per-step k``: a slow client, deciding every k-th tick and holding its commands
in between. ``--controller RUN_DIR`` (repeatable, one per leaf: a travel run corrects
"Step to cell", a drops run decides "Pick up drops"; ``graft.trained.
load_corrections``): every world is run twice, the tree alone and the tree with the
trained corrections, and the two are compared world by world (a sign test on the time to
diamond, a world without one counting as the time limit). ``--travel-while searching``
(repeatable) keeps the travel correction to the walks of those activities.
``--diamond-keep f``: harder worlds, each diamond vein kept with probability f (drawn
from the world seed; the mission's generatorOptions ``diamondKeep``).

Per world it prints the longest run of consecutive ticks with no action leaf running
("longest wait", and the waiting leaf it began in) and the watchdog's firings.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from minecraft.agent.corrections import Corrections  # noqa: E402
from minecraft.agent.diamond_tree import EpisodeResult, run_episode  # noqa: E402
from minecraft.agent.tree_profile import (  # noqa: E402
    ACTIVITIES,
    LeafTimes,
    Row,
    TimeProfile,
    aggregate,
)
from minecraft.malmo.client import MalmoClient  # noqa: E402
from minecraft.malmo.mission_xml import obtain_diamond  # noqa: E402
from minecraft.sim.server import WorldServer  # noqa: E402

TIME_LIMIT_TICKS = 24_000
TREE, CORRECTED = "tree alone", "tree + corrections"
Agent = tuple[tuple[str, ...], tuple[str, ...]]
"""The runs correcting the tree and the activities the travel correction walks in."""
_loaded: dict[Agent, Corrections] = {}


def _mission(seed: int, diamond_keep: float = 1.0) -> str:
    # The tree reads observations only: the small frame real Malmo needs, no 64x64 one.
    keep = None if diamond_keep == 1.0 else diamond_keep
    return obtain_diamond(seed=seed, pixels=False, diamond_keep=keep)


def corrections_of(agent: Agent) -> Corrections:
    """The trained corrections of an agent's runs, loaded once per process."""
    if agent not in _loaded:
        from graft.trained import load_corrections

        runs, travel_while = agent
        _loaded[agent] = load_corrections([Path(r) for r in runs], travel_while)
    return _loaded[agent]


def run_world(
    seed: int,
    max_ticks: int = TIME_LIMIT_TICKS + 5,
    ticks_per_step: int = 1,
    agent: Agent = ((), ()),
    diamond_keep: float = 1.0,
) -> tuple[EpisodeResult, float, LeafTimes]:
    """One world: a server on a free port, the tree (with the corrections of the
    ``agent``'s runs) through the client, profiled."""
    corrections = corrections_of(agent) if agent[0] else None
    t0 = time.perf_counter()
    profile = TimeProfile()
    with WorldServer(port=0, seed=seed) as server:
        client = MalmoClient("127.0.0.1", server.port, synchronous=True, seed=seed)
        client.init(_mission(seed, diamond_keep))
        try:
            result = run_episode(
                client, seed=seed, max_ticks=max_ticks, profile=profile,
                ticks_per_step=ticks_per_step, corrections=corrections,
            )  # fmt: skip
        finally:
            client.close()
    return result, time.perf_counter() - t0, profile.summary()


Job = tuple[int, int, int, Agent, float]


def _run_world(job: Job) -> tuple[Job, EpisodeResult, float, LeafTimes]:
    return job, *run_world(*job)


def _pct(x: float) -> str:
    return f"{100 * x:.1f}"


def time_tables(episodes: list[tuple[EpisodeResult, LeafTimes]], *, top: int = 15) -> str:
    """Markdown: where the time went per world, then per activity, sub-tree and leaf."""
    lines = ["| world seed | ticks | " + " | ".join(f"{a} %" for a in ACTIVITIES)
             + " | stuck ticks | idle re-entries | targets given up | running at the end |",
             "|---" * (len(ACTIVITIES) + 6) + "|"]  # fmt: skip
    for r, t in episodes:
        by = t.by("activity")
        total = t.total or 1
        lines.append(
            f"| {r.seed} | {t.total} | "
            + " | ".join(_pct(by.get(a, 0) / total) for a in ACTIVITIES)
            + f" | {sum(t.stuck_ticks.values())} | {sum(t.idle_entries.values())} | "
            f"{t.given_up} | {t.last.leaf} [{t.last.subtree}: {t.last.activity}] |"
        )
    times = [t for _, t in episodes]
    for attr, title, limit in (
        ("activity", "activity", None),
        ("subtree", "sub-tree (innermost need)", None),
        ("leaf", "leaf [sub-tree: activity]", top),
    ):
        rows = aggregate(times, attr)
        lines += ["", _rows_table(rows[:limit] if limit else rows, title)]
        if limit and len(rows) > limit:
            rest = sum(r.share for r in rows[limit:])
            lines.append(f"\n({len(rows) - limit} more leaves: {_pct(rest)} % of the time)")
    return "\n".join(lines)


def _rows_table(rows: list[Row], title: str) -> str:
    out = [f"| {title} | share % | mean ticks | median ticks | worlds | idle re-entries "
           "| stuck ticks |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    out += [
        f"| {r.name} | {_pct(r.share)} | {r.mean:.0f} | {r.median:.0f} | {r.worlds} | "
        f"{r.idle_entries} | {r.stuck} |"
        for r in rows
    ]
    return "\n".join(out)


def plot_time(agents: dict[str, list[tuple[EpisodeResult, LeafTimes]]], path: Path) -> None:
    """A stacked bar per world: in-game seconds by activity, a panel per agent (one
    y scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(agents)
    fig, axes = plt.subplots(n, 1, figsize=(10, 1.0 + 3.5 * n), sharey=True, squeeze=False)
    for ax, (name, episodes) in zip(axes[:, 0], agents.items(), strict=True):
        xs = [str(r.seed) for r, _ in episodes]
        bottom = [0.0] * len(episodes)
        for a in ACTIVITIES:
            ys = [t.by("activity").get(a, 0) / 20 for _, t in episodes]
            ax.bar(xs, ys, bottom=bottom, label=a)
            bottom = [b + y for b, y in zip(bottom, ys, strict=True)]
        ax.set_ylabel("in-game seconds")
        ax.set_title(f"Obtain-diamond tree: where the in-game time goes ({name})")
    axes[-1, 0].set_xlabel("world seed")
    axes[-1, 0].legend(ncol=len(ACTIVITIES), fontsize=8, loc="upper center",
                       bbox_to_anchor=(0.5, -0.18))  # fmt: skip
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _clock(ticks: int) -> str:
    s = ticks // 20
    return f"{s // 60}:{s % 60:02d}"


def outcome_table(results: list[tuple[EpisodeResult, float, LeafTimes]]) -> str:
    """Markdown: one row per world."""
    lines = ["| world seed | diamond | stage reached | in-game time (m:ss) | ticks | deaths | "
             "iron pickaxe at | drops left / decided | longest wait s [leaf] | "
             "watchdog firings | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for r, secs, prof in results:
        iron = r.reached.get("iron_pickaxe")
        wait = f"{prof.longest_wait / 20:.1f} [{prof.longest_wait_leaf.leaf}]"
        lines.append(
            f"| {r.seed} | {'yes' if r.diamond else 'no'} | {r.stage} | {_clock(r.ticks)} | "
            f"{r.ticks} | {r.deaths} | {_clock(iron) if iron is not None else '-'} | "
            f"{r.drops_left} / {r.drops_decided} | {wait} | {sum(prof.watchdog.values())} | "
            f"{secs:.0f} |"
        )
    got = [r for r, _, _ in results if r.diamond]
    median = _clock(int(statistics.median(r.ticks for r in got))) if got else "-"
    deaths = sum(r.deaths for r, _, _ in results)
    longest = max((p.longest_wait for _, _, p in results), default=0)
    fired = sum(sum(p.watchdog.values()) for _, _, p in results)
    lines += ["", f"diamonds: {len(got)}/{len(results)} worlds; deaths: {deaths}; "
              f"median time to diamond: {median}; longest wait: {longest / 20:.1f} s; "
              f"watchdog firings: {fired}"]  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=20, help="number of seeded worlds")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first world")
    ap.add_argument("--procs", type=int, default=2, help="worlds run in parallel")
    ap.add_argument("--png", type=Path, default=Path("diamond_time.png"),
                    help="where to write the time-per-world chart")  # fmt: skip
    ap.add_argument("--max-ticks", type=int, default=TIME_LIMIT_TICKS + 5,
                    help="game ticks before giving up (the mission ends at 24,000)")  # fmt: skip
    ap.add_argument("--ticks-per-step", type=int, default=1,
                    help="ticks each decision is held (a slow client; 1: every tick)")  # fmt: skip
    ap.add_argument("--controller", action="append", default=[], metavar="RUN_DIR",
                    help="a run correcting the leaf it trained for (repeatable)")  # fmt: skip
    ap.add_argument("--diamond-keep", type=float, default=1.0,
                    help="fraction of diamond veins each world keeps (1: all)")  # fmt: skip
    ap.add_argument("--travel-while", action="append", default=[], metavar="ACTIVITY",
                    help="the travel correction walks only in this activity's walks, "
                         "e.g. searching (repeatable; default: every walk)")  # fmt: skip
    args = ap.parse_args(argv)
    if min(args.worlds, args.procs, args.max_ticks, args.ticks_per_step) < 1:
        ap.error("--worlds, --procs, --max-ticks and --ticks-per-step must be at least 1")
    if not 0.0 <= args.diamond_keep <= 1.0:
        ap.error(f"--diamond-keep must be within [0, 1], got {args.diamond_keep}")
    controllers = tuple(args.controller)
    corrected: Agent = (controllers, tuple(args.travel_while))
    if controllers or args.travel_while:
        try:
            corrections_of(corrected)  # a wrong folder fails here, in one line
        except (ValueError, FileNotFoundError) as error:
            ap.error(str(error))
    seeds = list(range(args.first_seed, args.first_seed + args.worlds))
    agents: dict[str, Agent] = {TREE: ((), ())} | ({CORRECTED: corrected} if controllers else {})
    # World by world, the agents of one world together: pairs complete as the run goes.
    jobs = [
        (s, args.max_ticks, args.ticks_per_step, c, args.diamond_keep)
        for s in seeds
        for c in agents.values()
    ]
    t0 = time.perf_counter()
    done: dict[tuple[str, int], tuple[EpisodeResult, float, LeafTimes]] = {}
    label = {c: name for name, c in agents.items()}
    with mp.get_context("spawn").Pool(args.procs) as pool:
        for job, r, secs, prof in pool.imap_unordered(_run_world, jobs, chunksize=1):
            done[label[job[3]], r.seed] = (r, secs, prof)
            print(f"[{len(done)}/{len(jobs)}] {label[job[3]]}, seed {r.seed}: {r.stage}, "
                  f"{r.ticks} ticks, {r.deaths} deaths, longest wait {prof.longest_wait} "
                  f"ticks, {r.watchdog} firings, {secs:.0f} s",
                  file=sys.stderr, flush=True)  # fmt: skip
    wall = time.perf_counter() - t0
    runs = {name: [done[name, s] for s in seeds] for name in agents}
    for name, rows in runs.items():
        print(f"\n### {name} (one decision every {args.ticks_per_step} ticks)\n")
        print(outcome_table(rows))
    print(f"\nwall {wall:.0f} s with {args.procs} processes")
    if controllers:
        from diamond_compare import comparison  # bench/, beside this script

        print()
        print(comparison(runs[TREE], runs[CORRECTED], limit=args.max_ticks))
    for name, rows in runs.items():
        print(f"\n### where the time goes: {name}\n")
        print(time_tables([(r, prof) for r, _, prof in rows]))
    plot_time({name: [(r, prof) for r, _, prof in rows] for name, rows in runs.items()}, args.png)
    print(f"\nwrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
