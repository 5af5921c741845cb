"""Benchmark: the hierarchical method (policy over {tree, RL option}) against the tree alone.

Per seed, the documented commands (each seed in its own process):

    graft train --preset pendulum-options-residual --seed S --run-dir OUT/sS
    graft eval --policy OUT/sS --episodes 100 --seed 1000

and once `graft eval --policy hardcoded --preset pendulum-options --episodes 100 --seed
1000`: the tree on the same 100 episodes. Prints each seed's return, the mean over seeds
with its 95 % bootstrap interval, the same for the difference to the tree, and writes
OUT/hierarchical.png. On the same episodes it also evaluates each trained run with its
option choice changed: no switching margin (m = 0), and the RL option alone.

    python bench/hierarchical.py [--seeds 5] [--preset pendulum-options] [--set K=V] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
from pathlib import Path

from bench.seeds import GRAFT, SeedResult, format_ci, run_seeds


def tree_return(preset: str, *, episodes: int, seed: int) -> float:
    """The hard-coded tree's mean return on the evaluation episodes."""
    cmd = [*GRAFT, "eval", "--policy", "hardcoded", "--preset", preset]
    cmd += ["--episodes", str(episodes), "--seed", str(seed), "--json"]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return float(json.loads(out.strip().splitlines()[-1])["mean"])


def with_switch(run_dir: Path, margin: float) -> float:
    """The trained run's greedy policy over options with switching margin `margin`
    (−inf: always the RL option), on the 100 evaluation episodes."""
    from graft.api import evaluate
    from graft.trained import load_behaviour

    behaviour, config = load_behaviour(run_dir)
    behaviour.margin = margin
    return evaluate(behaviour.greedy, env=config.env_id, episodes=100, seed=1000).mean


def plot(results: list[SeedResult], tree: float, png: Path, title: str) -> None:
    """The evaluation curves of every seed against the tree's level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from service.metrics import read_metric

    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        steps, values = read_metric(r.run_dir / "metrics.csv", "eval/return_mean")
        ax.plot(steps, values, linewidth=0.9, label=f"seed {r.seed}: {r.mean:.1f} (100 ep.)")
    ax.axhline(tree, linestyle="--", color="tab:green", label=f"tree alone: {tree:.1f}")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("greedy return, 10 episodes")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="pendulum-options-residual")
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0 .. N-1")
    parser.add_argument("--parallel", type=int, default=1, help="seeds run side by side")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="K=V")
    parser.add_argument("--env-steps", type=int, default=None, help="default: the preset's")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-hierarchical"))
    args = parser.parse_args()

    setting = " ".join(f"--set {o}" for o in args.overrides) or "as committed"
    print(f"{args.preset} ({setting}), seeds 0–{args.seeds - 1}, {args.parallel} at a time")
    tree = tree_return(args.preset, episodes=100, seed=1000)
    print(f"tree alone, 100 episodes (eval seed 1000): {tree:.1f}")
    results = run_seeds(
        args.preset,
        range(args.seeds),
        args.out,
        overrides=args.overrides,
        env_steps=args.env_steps,
        parallel=args.parallel,
    )
    print("\n| seed | hierarchical, 100 episodes | − tree | same run, m = 0 | RL option alone |")
    print("|---|---|---|---|---|")
    no_margin, rl_alone = [], []
    for r in results:
        no_margin.append(with_switch(r.run_dir, 0.0))
        rl_alone.append(with_switch(r.run_dir, -math.inf))
        print(
            f"| {r.seed} | {r.mean:.1f} ± {r.std:.1f} | {r.mean - tree:+.1f} "
            f"| {no_margin[-1]:.1f} | {rl_alone[-1]:.1f} |",
            flush=True,
        )
    means = [r.mean for r in results]
    above = sum(m > tree for m in means)
    print(f"\nhierarchical, over seeds: {format_ci(means)}")
    print(f"minus the tree ({tree:.1f}): {format_ci([m - tree for m in means])}")
    print(f"{above} of {len(results)} seeds end above the tree")
    print(f"same runs, m = 0: {format_ci(no_margin)}; RL option alone: {format_ci(rl_alone)}")
    png = args.out / "hierarchical.png"
    plot(results, tree, png, f"{args.preset} ({setting}) vs the tree")
    print(f"figure: {png}")


if __name__ == "__main__":
    main()
