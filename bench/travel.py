"""Navigation benchmark of the Minecraft travel controller: the tree alone (a = μ(s)) and
the tree plus a trained backbone correction (a = μ(s) + clip(π(s), [−L, L])).

A fixed set of missions (``--worlds`` seeded worlds from ``--first-world``, ``--per-world``
destinations 10-30 blocks from each spawn, drawn with seed 0; training draws from worlds
1000-1063, so these are unseen), each a real world server driven through MalmoEnv,
synchronous (deterministic), ``--max-ticks`` per episode, ``--ticks-per-step`` game ticks
per decision (a slow client; default: the run's ``env_kwargs``, else 1), or
``--real-time`` (Malmo's asynchronous mode). "Stuck": the episode had at least one stuck
event (``travel_task``: no 1 block of progress along the route within 40 ticks). Time to
destination in game ticks (20 per second).

    python bench/travel.py --run runs/minecraft-backbone-s0 [--worlds 25 --per-world 4]
        [--procs 2] [--png docs/img/minecraft-backbone.png]
    python bench/travel.py [--ticks-per-step 6]     # the tree alone
"""

from __future__ import annotations

import argparse
import csv
import math
import multiprocessing as mp
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Optional

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graft.trained import load_behaviour, run_config  # noqa: E402
from minecraft.agent.travel_task import TravelMission, mission_pool  # noqa: E402
from minecraft.sim import worldgen  # noqa: E402

TREE, CORRECTED = "tree", "tree + correction"
RECOVERING = " (tree recovers when stalled)"


class Controller:
    """The tree alone (``run`` None), or the greedy policy of a trained run of any
    algorithm on the travel task (backbone: μ(s) + clip(π(s)); options: the policy over
    {tree, RL}), loaded the way ``graft eval`` loads one."""

    def __init__(
        self, run: Optional[str], checkpoint: Optional[str] = None, recover: bool = False
    ) -> None:
        from minecraft.agent.travel_env import TravelBackbone

        self.policy: Any = None
        self.behaviour: Any = None
        if run is None:
            self.policy = TravelBackbone()
            return
        try:
            self.behaviour, _ = load_behaviour(Path(checkpoint or run))
        except FileNotFoundError as error:
            raise SystemExit(f"bench/travel.py: {error}") from None
        if recover:  # the tree takes over from the correction when progress stalls
            from minecraft.agent.travel_env import correction_trusted

            self.behaviour.gate = correction_trusted
        self.policy = self.behaviour.greedy

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(self.policy(obs[None]))[0]


Job = tuple[str, Optional[str], Optional[str], list[TravelMission], list[int], dict[str, Any]]


def run_chunk(job: Job) -> list[dict]:
    """Episodes ``indices`` of ``missions`` with one controller, one world server."""
    import gymnasium as gym

    from minecraft.agent.travel_env import ENV_ID

    name, run, checkpoint, missions, indices, env_kwargs = job
    controller = Controller(run, checkpoint, recover=name.endswith(RECOVERING))
    env = gym.make(ENV_ID, missions=missions, **env_kwargs)
    rows = []
    try:
        for i in indices:
            obs, _ = env.reset(seed=i)
            total, info = 0.0, dict[str, Any]()
            while True:
                obs, r, terminated, truncated, info = env.step(controller(obs))
                total += float(r)
                if terminated or truncated:
                    break
            m = missions[i]
            rows.append(
                {
                    "controller": name,
                    "mission": i,
                    "world": m.world_seed,
                    "route_cells": len(m.route),
                    "arrived": bool(info["arrived"]),
                    "died": bool(info["died"]),
                    "ticks": int(info["ticks"]),
                    "stuck_events": int(info["stuck_events"]),
                    "return": round(total, 3),
                }
            )
    finally:
        env.close()
    return rows


def split_jobs(
    name: str,
    run: Optional[str],
    checkpoint: Optional[str],
    missions: list[TravelMission],
    env_kwargs: dict[str, Any],
    procs: int,
) -> list[Job]:
    """One controller's missions in ``4·procs`` interleaved chunks (even load per process)."""
    n = procs * 4
    return [
        (name, run, checkpoint, missions, list(range(k, len(missions), n)), env_kwargs)
        for k in range(n)
    ]


def checkpoint_curve(
    run: Path, missions: list[TravelMission], env_kwargs: dict[str, Any], procs: int,
    tree_rows: list[dict], png: Path, out: Path,
) -> None:  # fmt: skip
    """The benchmark over every checkpoint of ``run`` (the correction, ungated): success,
    episodes stuck and the time ratio to the tree against env steps, with the tree alone's
    levels; also ``out/curve.csv``."""
    from learner.checkpoint import load_checkpoint

    points = []
    with mp.get_context("spawn").Pool(procs) as pool:
        for ckpt in sorted((run / "checkpoints").glob("ckpt-*.pt")):
            jobs = split_jobs(CORRECTED, str(run), str(ckpt), missions, env_kwargs, procs)
            rows = [r for chunk in pool.map(run_chunk, jobs) for r in chunk]
            s, p = summarise(rows), paired_speed(tree_rows, rows)
            steps = int(load_checkpoint(ckpt)["loop"]["env_steps"])
            points.append((steps, 100 * s["success"], 100 * s["stuck"], p["ratio"]))
            print(f"{ckpt.name}: {steps} env steps, success {points[-1][1]:.0f}%, "
                  f"stuck {points[-1][2]:.0f}%, time ratio {p['ratio']:.3f} on "
                  f"{p['both']}", file=sys.stderr, flush=True)  # fmt: skip
    with open(out / "curve.csv", "w", newline="") as f:
        header = ("env_steps", "success_pct", "stuck_pct", "time_ratio_median")
        csv.writer(f).writerows([header, *points])
    plot_curve(points, summarise(tree_rows), png, f"{run.name}: benchmark over checkpoints")


def plot_curve(
    points: list[tuple[int, float, float, float]], tree: dict[str, float], png: Path, title: str
) -> None:
    """(env steps, success %, stuck %, time ratio) per checkpoint, with the tree's levels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps, success, stuck, ratio = zip(*points, strict=True)
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(7, 6), sharex=True, height_ratios=(3, 2))
    ax.plot(steps, success, "o-", color="tab:green", label="tree + correction: success")
    ax.plot(steps, stuck, "o-", color="tab:red", label="tree + correction: episodes stuck")
    ax.axhline(100 * tree["success"], color="tab:green", ls="--", label="tree alone: success")
    ax.axhline(100 * tree["stuck"], color="tab:red", ls="--", label="tree alone: episodes stuck")
    ax.set(ylabel="% of destinations", ylim=(-3, 103), title=title)
    ax.legend(fontsize=8)
    bx.plot(steps, ratio, "o-", color="tab:blue", label="tree + correction")
    bx.axhline(1.0, color="black", ls="--", label="tree alone")
    bx.set(xlabel="environment steps (checkpoint)",
           ylabel="time / tree's time\n(median, both arrived)")  # fmt: skip
    bx.legend(fontsize=8)
    for axis in (ax, bx):
        axis.grid(alpha=0.3)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def paired_speed(tree_rows: list[dict], rows: list[dict]) -> dict[str, float]:
    """Time against the tree's on the missions both reached: the median ratio, and on
    how many the controller was faster / slower."""
    tree = {r["mission"]: r["ticks"] for r in tree_rows if r["arrived"]}
    pairs = [
        (r["ticks"], tree[r["mission"]]) for r in rows if r["arrived"] and r["mission"] in tree
    ]
    faster, slower = sum(t < base for t, base in pairs), sum(t > base for t, base in pairs)
    return {
        "both": len(pairs),
        "ratio": statistics.median(t / base for t, base in pairs) if pairs else float("nan"),
        "faster": faster,
        "slower": slower,
        "sign_p": sign_test(faster, slower),
    }


def sign_test(wins: int, losses: int) -> float:
    """Two-sided sign test: the chance of a split at least this uneven if each (non-tied)
    mission were a coin flip."""
    n, k = wins + losses, min(wins, losses)
    return min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2**n) if n else 1.0


def summarise(rows: list[dict]) -> dict[str, float]:
    arrived = [r for r in rows if r["arrived"]]
    return {
        "episodes": len(rows),
        "success": len(arrived) / len(rows),
        "median_ticks": statistics.median(r["ticks"] for r in arrived) if arrived else float("nan"),
        "stuck": sum(r["stuck_events"] > 0 for r in rows) / len(rows),
        "stuck_events": sum(r["stuck_events"] for r in rows),
        "deaths": sum(r["died"] for r in rows),
        "mean_return": statistics.fmean(r["return"] for r in rows),
    }


def training_curve(run: Path, png: Path, tree_level: float) -> None:
    """The run's evaluation return against env steps, with the tree alone's level."""
    from service.metrics import plot_learning_curve

    png.parent.mkdir(parents=True, exist_ok=True)
    plot_learning_curve(
        run / "metrics.csv",
        png,
        title="minecraft-backbone: evaluation return (8 training-world missions)",
        reference={"tree alone (same missions)": tree_level},
    )


def tree_eval_level(run: Path) -> float:
    """The tree alone's mean return on the evaluator's episodes of ``run`` (same seeds,
    same environment settings)."""
    from actors.evaluator import run_episodes
    from minecraft.agent.travel_env import TravelBackbone

    config = run_config(run)
    returns = run_episodes(
        TravelBackbone(),
        env=config.env_spec(),
        episodes=config.eval_episodes,
        seed=10_000 + config.seed,
    )
    return float(returns.mean())


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", help="a minecraft-backbone run folder (omit: the tree alone)")
    ap.add_argument("--label", default=CORRECTED, help="the trained controller's name")
    ap.add_argument("--checkpoint", help="a checkpoint of --run (default: its latest)")
    ap.add_argument("--worlds", type=int, default=25)
    ap.add_argument("--first-world", type=int, default=0)
    ap.add_argument("--per-world", type=int, default=4, help="destinations per world")
    ap.add_argument("--max-ticks", type=int, default=600)
    ap.add_argument("--procs", type=int, default=2)
    ap.add_argument("--real-time", action="store_true", help="Malmo's asynchronous mode")
    ap.add_argument("--ticks-per-step", type=int,
                    help="synchronous: ticks per decision, a slow client (default: --run's "
                         "env_kwargs, else 1)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=Path("runs/bench-travel"))
    ap.add_argument("--png", type=Path, help="also draw the run's training curve here")
    ap.add_argument("--curve", type=Path,
                    help="also benchmark every checkpoint of --run (the correction alone) "
                         "and draw success and stuck episodes against env steps here")  # fmt: skip
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    worlds = list(range(args.first_world, args.first_world + args.worlds))
    missions = mission_pool(worlds, args.per_world, seed=0, terrain_of=worldgen.generate)
    print(f"{len(missions)} missions in {len(worlds)} worlds ({time.perf_counter() - t0:.0f} s)",
          file=sys.stderr, flush=True)  # fmt: skip
    try:
        trained = run_config(Path(args.run)) if args.run else None
    except FileNotFoundError as error:
        raise SystemExit(f"bench/travel.py: {error}") from None
    controllers = [(TREE, None)]
    if trained:
        controllers.append((args.label, args.run))
        if trained.algorithm == "backbone_td3":  # the gate acts on a correction
            controllers.append((args.label + RECOVERING, args.run))
    if args.ticks_per_step is None:  # the conditions the run trained in
        args.ticks_per_step = int((trained.env_kwargs if trained else {}).get("ticks_per_step", 1))
    env_kwargs = {
        "max_ticks": args.max_ticks,
        "real_time": args.real_time,
        "ticks_per_step": args.ticks_per_step,
    }
    jobs = [
        job
        for name, run in controllers
        for job in split_jobs(name, run, args.checkpoint, missions, env_kwargs, args.procs)
    ]
    rows: list[dict] = []
    with mp.get_context("spawn").Pool(args.procs) as pool:
        for chunk in pool.imap_unordered(run_chunk, jobs):
            rows.extend(chunk)
            done = {n: sum(r["controller"] == n for r in rows) for n, _ in controllers}
            print(f"[{time.perf_counter() - t0:.0f} s] episodes done: {done}",
                  file=sys.stderr, flush=True)  # fmt: skip
    rows.sort(key=lambda r: (r["controller"], r["mission"]))
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    mode = "real time" if args.real_time else f"synchronous, {args.ticks_per_step} ticks per step"
    print(f"\n{len(missions)} destinations, worlds {worlds[0]}-{worlds[-1]}, "
          f"max {args.max_ticks} ticks, {mode}\n")  # fmt: skip
    print("| controller | success | median ticks to destination | episodes stuck | "
          "stuck events | deaths | mean return |")  # fmt: skip
    print("|---|---|---|---|---|---|---|")
    for name, _ in controllers:
        s = summarise([r for r in rows if r["controller"] == name])
        print(f"| {name} | {100 * s['success']:.0f}% | {s['median_ticks']:.0f} | "
              f"{100 * s['stuck']:.0f}% | {s['stuck_events']} | {s['deaths']} | "
              f"{s['mean_return']:.2f} |")  # fmt: skip
    if args.run:
        tree_rows = [r for r in rows if r["controller"] == TREE]
        for name, _ in controllers[1:]:
            p = paired_speed(tree_rows, [r for r in rows if r["controller"] == name])
            print(f"\n{name}: missions both reached: {p['both']}; time ratio to the tree: "
                  f"median {p['ratio']:.3f}; faster on {p['faster']}, slower on "
                  f"{p['slower']} (sign test p = {p['sign_p']:.2g})")  # fmt: skip
        if args.png:
            level = tree_eval_level(Path(args.run))
            training_curve(Path(args.run), args.png, level)
            print(f"training curve: {args.png} (tree alone on the evaluator's missions: "
                  f"{level:.2f})")  # fmt: skip
    if args.run and args.curve:
        checkpoint_curve(
            Path(args.run), missions, env_kwargs, args.procs, tree_rows, args.curve, args.out
        )
        print(f"benchmark over checkpoints: {args.curve}, {args.out / 'curve.csv'}")
    print(f"wall {time.perf_counter() - t0:.0f} s with {args.procs} processes; "
          f"episodes: {args.out / 'episodes.csv'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
