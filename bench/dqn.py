"""Benchmark: Double DQN (`cartpole-ddqn`) over seeds, the final policy at 50k env steps.

Per seed, exactly the documented commands (each seed in its own process):

    graft train --preset cartpole-ddqn --seed S --run-dir OUT/sS
    graft eval --policy OUT/sS --episodes 100 --seed 1000

Prints each seed's 100-episode return, how many seeds reach ≥ 475, the mean over seeds with
its 95 % bootstrap interval, and writes OUT/dqn.png (the final returns, and the 10-episode
evaluation curves during training).

    python bench/dqn.py [--seeds 10] [--parallel 2] [--set dqn.n_step=1] [--out DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from bench.seeds import SeedResult, format_ci, run_seeds

THRESHOLD = 475.0


def plot(results: list[SeedResult], png: Path, title: str) -> None:
    """Left: each seed's final 100-episode return; right: its evaluation curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from service.metrics import read_metric

    fig, (bars, curves) = plt.subplots(1, 2, figsize=(11, 4))
    seeds = [r.seed for r in results]
    colours = ["tab:blue" if r.mean >= THRESHOLD else "tab:red" for r in results]
    bars.bar(seeds, [r.mean for r in results], yerr=[r.std for r in results], color=colours)
    bars.axhline(THRESHOLD, linestyle="--", color="grey", label=f"{THRESHOLD:.0f}")
    bars.set_xlabel("seed")
    bars.set_ylabel("final policy, mean return over 100 episodes (± std)")
    bars.set_xticks(seeds)
    bars.legend(loc="lower right")
    for r in results:
        steps, values = read_metric(r.run_dir / "metrics.csv", "eval/return_mean")
        curves.plot(steps, values, linewidth=0.8, label=f"seed {r.seed}")
    curves.axhline(THRESHOLD, linestyle="--", color="grey")
    curves.set_xlabel("environment steps")
    curves.set_ylabel("greedy return, 10 episodes")
    curves.legend(fontsize=7, ncol=2, loc="lower right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--preset", default="cartpole-ddqn")
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0 .. N-1")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--parallel", type=int, default=2, help="seeds run side by side")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="K=V")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-dqn"))
    args = parser.parse_args()

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    setting = " ".join(f"--set {o}" for o in args.overrides) or "as committed"
    print(f"{args.preset} ({setting}), seeds {seeds[0]}–{seeds[-1]}, {args.parallel} at a time")
    results = run_seeds(
        args.preset, seeds, args.out, overrides=args.overrides, parallel=args.parallel
    )
    print("\n| seed | final policy, 100 episodes |\n|---|---|")
    for r in results:
        print(f"| {r.seed} | {r.mean:.1f} ± {r.std:.1f} |")
    means = [r.mean for r in results]
    hits = sum(m >= THRESHOLD for m in means)
    print(f"\n{hits} of {len(results)} seeds ≥ {THRESHOLD:.0f}")
    print(f"over seeds: {format_ci(means)}")
    png = args.out / "dqn.png"
    plot(results, png, f"{args.preset} ({setting}): {hits}/{len(results)} seeds ≥ 475")
    print(f"figure: {png}")


if __name__ == "__main__":
    main()
