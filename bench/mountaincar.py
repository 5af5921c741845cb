"""Benchmark: the MountainCarContinuous example (examples/mountaincar) over several seeds.

Plain TD3, the energy-pumping tree alone, backbone TD3 on that tree and the hierarchical
options over it (the tree or TD3 every 10 steps), at one fixed budget of env steps: per
method, the seeds whose final policy reaches the flag in every final episode, the success
rate over all final episodes (reaching the flag), the mean return, and the seeds whose
every in-run evaluation (from the first) reached the flag.
Prints a table and writes a PNG of the evaluation returns over env steps.

    python bench/mountaincar.py [--seeds 5] [--env-steps 10000] [--episodes 20] [--parallel 2]
        [--methods td3,backbone,backbone-narrow,options]
    python bench/mountaincar.py --quick    # a smoke run: 1 seed, tiny budgets

The example package must be installed (``pip install -e examples/mountaincar``).
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray

import graft
from graft.config import load_preset
from graft.orchestration.launcher import train

PRESETS = Path(__file__).resolve().parents[1] / "examples" / "mountaincar" / "presets"
TRAINED = {
    "td3": "plain TD3",
    "backbone": "backbone TD3",
    "backbone-narrow": "backbone TD3, correction within ±0.7",
    "options": "options (the tree or TD3 every 10 steps)",
}
"""Preset file stem -> the method's name in the table."""
DEFAULT_METHODS = ("td3", "backbone", "backbone-narrow")
"""Run when --methods is not given (options: `--methods options`)."""
COLORS = {
    "td3": "tab:red",
    "backbone": "tab:blue",
    "backbone-narrow": "tab:purple",
    "options": "tab:orange",
}
TREE = "tree alone"
QUICK = {
    "learning_starts": 200,
    "eval_every": 300,
    "eval_episodes": 1,
    "td3": {"batch_size": 32, "burn_in_updates": 20, "frozen_actor_updates": 20},
}
"""--quick: a smoke run of the whole benchmark in about a minute (not a result)."""


@ray.remote(num_cpus=0.25)
def train_one(
    preset: str, *, seed: int, env_steps: int, out: Path, quick: bool, address: str
) -> dict[str, Any]:
    """Trains one method for one seed (a full `train` run inside a Ray task); its in-run
    evaluations and the run folder."""
    import torch

    torch.set_num_threads(1)
    overrides: dict[str, Any] = {"seed": seed, "env_steps": env_steps}
    if quick:
        overrides.update(QUICK)
    config = load_preset(PRESETS / f"{preset}.yaml", **overrides)
    result = train(config, run_dir=out / f"{preset}-s{seed}", progress=False, address=address)
    return {
        "preset": preset,
        "seed": seed,
        "run_dir": result.run_dir,
        "steps": [e["tag"]["env_steps"] for e in result.evaluations],
        "returns": [e["mean"] for e in result.evaluations],
        "reached": [e["stats"].get("reached", float("nan")) for e in result.evaluations],
    }


def final_episodes(policy: Any, *, episodes: int, seed: int) -> dict[str, np.ndarray]:
    """Deterministic final episodes (episode i reset with seed + i): returns and reached."""
    result = graft.evaluate(policy, episodes=episodes, seed=seed)
    return {"returns": result.returns, "reached": result.metrics["reached"]}


def eval_seed(seed: int) -> int:
    """First reset seed of a training seed's final episodes: none a run's actors or its
    in-run evaluations (reset from 10,000 + the run's seed) used."""
    return 100_000 + 1_000 * seed


def summarise(
    method: str, finals: Sequence[dict[str, np.ndarray]], runs: Sequence[Optional[dict]]
) -> dict[str, Any]:
    """One table row: a method's final episodes over seeds (and its in-run evaluations)."""
    seed_means = np.array([f["returns"].mean() for f in finals])
    reached = np.concatenate([f["reached"] for f in finals])
    trained = [r for r in runs if r is not None]
    return {
        "method": method,
        "seeds": len(finals),
        "seeds_always_reaching": int(sum(bool(np.all(f["reached"] == 1.0)) for f in finals)),
        "success_rate": float(reached.mean()),
        "return_mean": float(seed_means.mean()),
        "return_std_over_seeds": float(seed_means.std()),
        # Every in-run evaluation, the first included, reached the flag in all its episodes.
        "seeds_reaching_from_first_eval": (
            int(sum(bool(np.all(np.array(r["reached"]) == 1.0)) for r in trained))
            if trained
            else None
        ),
    }


def table(rows: Sequence[dict[str, Any]], *, env_steps: int, episodes: int) -> str:
    """The Markdown table docs/results.md quotes."""
    lines = [
        f"MountainCarContinuous-v0, {env_steps} env steps per run, final policy scored on "
        f"{episodes} deterministic episodes per seed",
        "",
        "| method | seeds reaching the flag in every final episode | success rate (episodes) "
        "| mean return ± std over seeds | seeds reaching the flag from the first evaluation on |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        first = (
            "–"
            if r["seeds_reaching_from_first_eval"] is None
            else f"{r['seeds_reaching_from_first_eval']}/{r['seeds']}"
        )
        lines.append(
            f"| {r['method']} | {r['seeds_always_reaching']}/{r['seeds']} "
            f"| {r['success_rate']:.0%} "
            f"| {r['return_mean']:.2f} ± {r['return_std_over_seeds']:.2f} "
            f"| {first} |"
        )
    return "\n".join(lines)


def plot(runs: dict[str, list[dict]], tree_return: float, png: Path) -> None:
    """Evaluation return over env steps: each seed thin, the mean thick; the tree dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4))
    for preset, seeds in runs.items():
        color = COLORS[preset]
        length = min(len(r["steps"]) for r in seeds)
        steps = np.array(seeds[0]["steps"][:length])
        values = np.array([r["returns"][:length] for r in seeds])
        for v in values:
            ax.plot(steps, v, color=color, alpha=0.25, linewidth=0.8)
        ax.plot(
            steps,
            values.mean(0),
            color=color,
            label=f"{TRAINED[preset]}, mean of {len(seeds)} seeds",
        )
    ax.axhline(
        tree_return, linestyle="--", color="tab:green", label=f"tree alone ({tree_return:.1f})"
    )
    ax.set_xlabel("environment steps")
    ax.set_ylabel("evaluation return")
    ax.set_title("MountainCarContinuous-v0 (return > 0 iff the car reached the flag)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main(argv: Optional[Sequence[str]] = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--env-steps", type=int, default=10_000)
    parser.add_argument("--episodes", type=int, default=20, help="final episodes per seed")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-mountaincar"))
    parser.add_argument("--parallel", type=int, default=2, help="runs at a time")
    parser.add_argument(
        "--methods",
        default=",".join(DEFAULT_METHODS),
        help=f"the trained methods, by preset, of {','.join(TRAINED)} "
        f"(default: {','.join(DEFAULT_METHODS)})",
    )
    parser.add_argument("--quick", action="store_true", help="1 seed, 600 env steps, 2 episodes")
    args = parser.parse_args(argv)
    if args.quick:
        args.seeds, args.env_steps, args.episodes = 1, 600, 2
    methods = args.methods.split(",")
    unknown = sorted(set(methods) - set(TRAINED))
    if unknown:
        parser.error(f"--methods: unknown {unknown}; choose from {','.join(TRAINED)}")

    started_ray = not ray.is_initialized()
    if started_ray:
        # A run takes 0.75 logical CPUs (its task, one actor, the evaluator).
        cpus = max(os.cpu_count() or 1, args.parallel)
        for attempt in range(3):  # a loaded machine can miss Ray's 30 s raylet start-up wait
            try:
                ray.init(
                    num_cpus=cpus,
                    include_dashboard=False,
                    log_to_driver=False,
                    configure_logging=False,
                )
                break
            except Exception as error:  # noqa: BLE001 - Ray raises a bare Exception here
                print(f"Ray did not start ({error}); retrying", flush=True)
                ray.shutdown()
                if attempt == 2:
                    raise
    address = ray.get_runtime_context().gcs_address
    tree = graft.load_policy("hardcoded", preset=PRESETS / "backbone.yaml")
    finals: dict[str, list[dict]] = {method: [] for method in (*methods, TREE)}
    for seed in range(args.seeds):
        finals[TREE].append(final_episodes(tree, episodes=args.episodes, seed=eval_seed(seed)))
    jobs = [(preset, seed) for seed in range(args.seeds) for preset in methods]
    runs: dict[str, dict[int, dict]] = {preset: {} for preset in methods}
    pending: dict[Any, tuple[str, int]] = {}
    start = time.perf_counter()
    while jobs or pending:
        while jobs and len(pending) < args.parallel:
            preset, seed = jobs.pop(0)
            print(f"started {TRAINED[preset]}, seed {seed}", flush=True)
            ref = train_one.remote(
                preset,
                seed=seed,
                env_steps=args.env_steps,
                out=args.out,
                quick=args.quick,
                address=address,
            )
            pending[ref] = (preset, seed)
        (ready,), _ = ray.wait(list(pending), num_returns=1)
        preset, seed = pending.pop(ready)
        run = runs[preset][seed] = ray.get(ready)
        final = final_episodes(run["run_dir"], episodes=args.episodes, seed=eval_seed(seed))
        finals[preset].append(final)
        done, total = sum(len(r) for r in runs.values()), args.seeds * len(methods)
        elapsed = time.perf_counter() - start
        print(
            f"[{done}/{total}] {TRAINED[preset]}, seed {seed}: final return "
            f"{final['returns'].mean():.2f}, reached the flag in {int(final['reached'].sum())}/"
            f"{args.episodes} episodes; evaluations {[round(r, 1) for r in run['returns']]}; "
            f"{elapsed / 60:.1f} min elapsed, ~{elapsed / done * (total - done) / 60:.1f} min left",
            flush=True,
        )
    if started_ray:
        ray.shutdown()

    trained = {p: [runs[p][s] for s in sorted(runs[p])] for p in methods}
    rows = [summarise(TREE, finals[TREE], [None] * args.seeds)]
    rows += [summarise(TRAINED[p], finals[p], trained[p]) for p in methods]
    print()
    print(table(rows, env_steps=args.env_steps, episodes=args.episodes))
    png = args.out / "mountaincar.png"
    plot(trained, float(np.mean([f["returns"].mean() for f in finals[TREE]])), png)
    print(f"\nplot: {png}; wall time {(time.perf_counter() - start) / 60:.1f} min")
    return rows


if __name__ == "__main__":
    main()
