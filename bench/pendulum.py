"""Benchmark: pendulum-td3 through the full service, several seeds.

Prints per seed the env steps and wall time until the mean deterministic evaluation
return over 100 episodes first reaches -200, the return at the end of the budget,
the learner's fraction of time waiting on the replay server, and its updates/s beside
a same-process baseline: the identical update loop on an in-memory batch. Then, over
the seeds, the mean and IQM of the final return and of the env steps to -200, each with
its 95 % bootstrap confidence interval (graft/experiments/stats.py).

    python bench/pendulum.py [--seeds 5] [--env-steps 20000]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import ray
import torch

from graft.config import TrainConfig, load_preset
from graft.experiments.stats import summarize
from graft.orchestration.launcher import train
from learner.loop import to_tensors
from learner.td3.builder import make_td3_learner

THRESHOLD = -200.0


def baseline_updates_per_s(config: TrainConfig, updates: int = 1000) -> float:
    """The learner's update loop alone, on one fixed in-memory batch (same threads)."""
    env = gym.make(config.env_id)
    learner = make_td3_learner(env.observation_space, env.action_space, config.td3, config.seed)
    rng = np.random.default_rng(0)
    b = config.td3.batch_size
    batch = {
        "obs": rng.normal(size=(b, 3)).astype(np.float32),
        "action": rng.normal(size=(b, 1)).astype(np.float32),
        "reward": rng.normal(size=b).astype(np.float32),
        "terminated": np.zeros(b, bool),
        "truncated": np.zeros(b, bool),
        "next_obs": rng.normal(size=(b, 3)).astype(np.float32),
    }
    for _ in range(50):
        learner.update(to_tensors(batch))
    start = time.perf_counter()
    for _ in range(updates):
        learner.update(to_tensors(batch))  # includes the same host-to-tensor copy
    return updates / (time.perf_counter() - start)


def plot_seeds(out: Path, seeds: int, png: Path) -> None:
    """Mean ± std over seeds of the evaluation return, with the hard-coded level."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from service.metrics import read_metric

    curves = [
        read_metric(out / f"seed{s}" / "metrics.csv", "eval/return_mean") for s in range(seeds)
    ]
    length = min(len(values) for _, values in curves)
    steps = np.array(curves[0][0][:length])
    values = np.array([v[:length] for _, v in curves])
    fig, ax = plt.subplots(figsize=(6, 4))
    for v in values:
        ax.plot(steps, v, color="tab:blue", alpha=0.25, linewidth=0.8)
    mean, std = values.mean(0), values.std(0)
    ax.plot(steps, mean, color="tab:blue", label=f"TD3 through graft, mean of {seeds} seeds")
    ax.fill_between(steps, mean - std, mean + std, color="tab:blue", alpha=0.2)
    ax.axhline(-429.0, linestyle="--", color="tab:green", label="hard-coded policy (-429)")
    ax.axhline(THRESHOLD, linestyle=":", color="grey", label="-200")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("mean return, 100 deterministic episodes")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--env-steps", type=int, default=20_000)
    parser.add_argument("--eval-episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("runs/bench-pendulum"))
    args = parser.parse_args()

    torch.set_num_threads(1)  # as the learner in `graft train`
    ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
    rows = []
    for seed in range(args.seeds):
        config = load_preset(
            "pendulum-td3", seed=seed, env_steps=args.env_steps, eval_episodes=args.eval_episodes
        )
        result = train(config, run_dir=args.out / f"seed{seed}", progress=False)
        reached = next((e for e in result.evaluations if e["mean"] >= THRESHOLD), None)
        s = result.summary
        row = {
            "seed": seed,
            "steps_to_-200": reached["tag"]["env_steps"] if reached else None,
            "wall_s_to_-200": round(reached["tag"]["wall_s"], 1) if reached else None,
            "final_return": round(s["final_eval_return_mean"], 1),
            "final_env_steps": s["env_steps"],
            "run_wall_s": s["wall_s"],
            "learner_wait_fraction": s["learner_wait_fraction"],
            "learner_updates_per_s": s["learner_updates_per_s"],
            "baseline_updates_per_s": round(baseline_updates_per_s(config), 1),
        }
        row["updates_ratio"] = round(
            row["learner_updates_per_s"] / row["baseline_updates_per_s"], 2
        )
        rows.append(row)
        print(json.dumps(row), flush=True)
    ray.shutdown()

    print(
        f"\npendulum-td3, {args.env_steps} env steps, eval = mean of {args.eval_episodes} "
        "deterministic episodes every 1000 env steps"
    )
    print(
        "| seed | env steps to ≥ -200 | wall s to ≥ -200 | return at end | learner wait "
        "| learner upd/s | baseline upd/s | ratio |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['seed']} | {r['steps_to_-200'] or 'not reached'} | "
            f"{r['wall_s_to_-200'] or '-'} | {r['final_return']} | "
            f"{100 * r['learner_wait_fraction']:.1f}% | {r['learner_updates_per_s']} | "
            f"{r['baseline_updates_per_s']} | {r['updates_ratio']} |"
        )
    plot_seeds(args.out, args.seeds, args.out / "pendulum-td3.png")
    print(f"curves: {args.out / 'pendulum-td3.png'}")
    reached = [r["steps_to_-200"] for r in rows if r["steps_to_-200"] is not None]
    print(
        f"\n{len(reached)}/{len(rows)} seeds reached {THRESHOLD} within {args.env_steps} env steps"
    )
    print(f"return at end: {summarize([r['final_return'] for r in rows]).line()}")
    if reached:
        print(
            f"env steps to ≥ {THRESHOLD:.0f} (seeds that reached it): {summarize(reached).line(0)}"
        )


if __name__ == "__main__":
    main()
