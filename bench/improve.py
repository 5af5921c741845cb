"""Benchmark: does graft improve a user's hard-coded policy, and never make it worse?

Each task is a user's own preset (an environment, a tree, a budget, and no algorithm, so
it trains with graft's default recipe). Per task and seed, exactly the documented
commands, each in its own process (`bench/seeds.py`):

    graft train --preset TASK.yaml --seed S --run-dir OUT/TASK/sS
    graft eval --policy OUT/TASK/sS --episodes 50 --seed 100000+1000·S

and the tree alone on the same 50 episodes (reset seeds no run used: actors and in-run
evaluations reset from small seeds and 10,000 + S). Per task it reports the tree's score,
each seed's final score, the mean improvement over the tree (final minus tree on the same
episodes) with its 95 % bootstrap interval over seeds (`service.run.experiments.stats`),
the worst in-run evaluation relative to the tree on the same episodes, env steps and wall
time; prints a table, writes OUT/improve.json and OUT/improve.png.

    python -m bench.improve --task lunarlander --seeds 5 [--env-steps N] [--set k=v ...]
    python -m bench.improve --suite --seeds 5
    python -m bench.improve --task pendulum --quick   # a smoke run: 1 seed, 600 steps, 10 episodes
    python -m bench.improve --task lunarlander --seeds 5 --parts   # + each part's share

With ``--parts`` each seed's networks are also scored without the final selection and
without switching too, on the same episodes (`bench/improve_parts.py`).

The examples must be installed (``pip install -e examples/mountaincar examples/cartpole
examples/lunarlander examples/halfcheetah``). A seed whose run finished is read back, not
re-run.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

import graft
from bench.improve_parts import part_scores, parts_table, reselect
from bench.seeds import run_seed
from service.metrics import read_metric
from service.run.config import load_preset
from service.run.experiments.plots import curves
from service.run.experiments.stats import MIN_SEEDS, summarize
from service.run.seeds import evaluation_seed, held_out_seed

REPO = Path(__file__).resolve().parents[1]
TASKS = {
    "pendulum": REPO / "bench" / "tasks" / "pendulum.yaml",
    "mountaincar": REPO / "examples" / "mountaincar" / "presets" / "recipe.yaml",
    "cartpole": REPO / "examples" / "cartpole" / "presets" / "recipe.yaml",
    "lunarlander": REPO / "examples" / "lunarlander" / "presets" / "recipe.yaml",
    "lunarlander-discrete": REPO / "examples" / "lunarlander" / "presets" / "recipe-discrete.yaml",
    "halfcheetah": REPO / "examples" / "halfcheetah" / "presets" / "recipe.yaml",
}
"""Task name -> a user's preset: environment, hard-coded policy, budget, no algorithm."""
_LAYOUT = ("num_actors=1", "envs_per_actor=4")  # the recipe's actors: only the method differs
_DQN = (*_LAYOUT, "algorithm=ddqn", "dqn.hidden_sizes=[256,256]")
_TD3 = (*_LAYOUT, "algorithm=td3", "updates_per_env_step=1.0", "td3.hidden_sizes=[256,256]",
        "td3.batch_size=256", "td3.actor_lr=0.001", "td3.critic_lr=0.001")  # fmt: skip
SCRATCH: dict[str, tuple[str, ...]] = {
    # graft's cartpole-ddqn preset (rl-baselines3-zoo's CartPole DQN, made to hold its policy)
    "cartpole": (*_DQN, "learning_starts=1000", "updates_per_env_step=0.5",
                 "dqn.learning_rate=0.0023", "dqn.learning_rate_end=0.0", "dqn.batch_size=128",
                 "dqn.n_step=3", "dqn.target_update_every=1", "dqn.target_tau=0.005",
                 "dqn.epsilon_start=1.0", "dqn.epsilon_end=0.01",
                 "dqn.epsilon_decay_env_steps=8000"),  # fmt: skip
    # zoo's LunarLander DQN: lr 6.3e-4, batch 128, target every 250 steps, ε → 0.1 over 12 %
    "lunarlander-discrete": (*_DQN, "learning_starts=1000", "updates_per_env_step=1.0",
                             "dqn.learning_rate=0.00063", "dqn.batch_size=128",
                             "dqn.target_update_every=250", "dqn.epsilon_start=1.0",
                             "dqn.epsilon_end=0.1", "dqn.epsilon_decay_env_steps=3600"),  # fmt: skip
    # zoo's TD3 (SB3 defaults: lr 1e-3; Pendulum and LunarLanderContinuous: γ 0.98, 10k
    # random steps first; MountainCarContinuous: noise 0.5; HalfCheetah: 10k random steps)
    "pendulum": (*_TD3, "learning_starts=10000", "td3.gamma=0.98", "td3.exploration_noise=0.1"),
    "lunarlander": (*_TD3, "learning_starts=10000", "td3.gamma=0.98",
                    "td3.exploration_noise=0.1"),  # fmt: skip
    "mountaincar": (*_TD3, "learning_starts=1000", "td3.exploration_noise=0.5"),
    "halfcheetah": (*_TD3, "learning_starts=10000", "td3.exploration_noise=0.1"),
}
"""Task name -> the from-scratch arm's settings on the task's preset: graft's own Double
DQN or TD3, no tree, 256x256 networks, rl-baselines3-zoo's hyper-parameters for the task
where it has them (its LunarLander DQN's ε decays over 12 % of its 100k steps: 3,600 of a
30k budget). A baseline a user would run, not tuned here."""
EPISODES = 50
"""Final evaluation episodes per seed (the tree's score uses the same ones)."""
QUICK_EPISODES = 10
"""--quick's final evaluation episodes: enough to see the pipeline work, not a result."""
BURN_IN_FRACTION = 0.1
"""In-run evaluations before this fraction of the budget are not held to the tree."""
WORST_DROP = 0.1
"""Target: no in-run evaluation (after the first tenth) below the tree by more than this
fraction of the tree's |score|."""
QUICK = {
    "learning_starts": 200,
    "eval_every": 300,
    "eval_episodes": 2,
    "td3.batch_size": 32,
    "td3.burn_in_updates": 20,
    "td3.frozen_actor_updates": 20,
    "dqn.batch_size": 32,
    "dqn.burn_in_updates": 20,
    "selection.episodes": 2,
}
"""--quick: a smoke run of the whole pipeline in a minute or two (not a result); its
final selection plays 2 episodes each for the policy and the tree, not the recipe's 30."""


def final_seed(seed: int) -> int:
    """First reset seed of training seed `seed`'s final episodes (held out: no run plays
    them, `service.run.seeds`)."""
    return held_out_seed(seed)


def in_run_seed(seed: int) -> int:
    """First reset seed of a run's in-run evaluations and final selection."""
    return evaluation_seed(seed)


@dataclass(frozen=True)
class SeedRow:
    """One seed of one task."""

    seed: int
    tree: float
    """The tree's mean return on this seed's final episodes."""
    final: float
    """The trained policy's mean return on the same episodes."""
    tree_in_run: float
    """The tree's mean return on the run's in-run evaluation episodes."""
    steps: list[int]
    evaluations: list[float]
    """The run's in-run evaluations (mean returns) and their env steps."""
    env_steps: int
    wall_s: float
    parts: dict[str, float] = field(default_factory=dict)
    """With --parts: the final networks' variants on the final episodes (improve_parts)."""
    guarded: list[float] = field(default_factory=list)
    """What the run would play had it stopped at each in-run evaluation (the selection's
    verdict on it, `guard/return_mean`); empty for a run without a selection."""

    @property
    def improvement(self) -> float:
        return self.final - self.tree


def worst_drop(row: SeedRow, budget: int, *, guarded: bool = False) -> float:
    """The worst in-run evaluation after the first tenth of the budget (of the policy, or
    with `guarded` of what a run stopped there plays), minus the tree's score on the same
    episodes, as a fraction of the tree's |score| (negative: below it); NaN when no
    evaluation came after the first tenth."""
    values = row.guarded if guarded else row.evaluations
    if len(values) != len(row.steps):
        return math.nan
    after = [e for s, e in zip(row.steps, values, strict=True) if s > BURN_IN_FRACTION * budget]
    if not after:
        return math.nan
    return (min(after) - row.tree_in_run) / max(abs(row.tree_in_run), 1e-9)


def run_task(
    task: str,
    *,
    seeds: Sequence[int],
    out: Path,
    overrides: Sequence[str],
    env_steps: Optional[int],
    quick: bool = False,
    episodes: int = EPISODES,
    parts: bool = False,
    reselected: bool = False,
) -> tuple[dict[str, Any], list[SeedRow]]:
    """Trains and scores every seed of one task; its summary row and per-seed rows."""
    preset = TASKS[task]
    config = load_preset(preset, **({"env_steps": env_steps} if env_steps else {}))
    if quick:  # the sections the task's method reads (the others would be refused)
        unused = "td3." if config.algorithm == "ddqn" else "dqn."
        given = {o.split("=")[0] for o in overrides}
        extra = [
            f"{k}={v}" for k, v in QUICK.items() if not k.startswith(unused) and k not in given
        ]
        overrides = [*overrides, *extra]
    settings = dict(o.split("=", 1) for o in overrides)
    budget = env_steps or config.env_steps
    tree = graft.load_policy("hardcoded", preset=preset)
    rows: list[SeedRow] = []
    for seed in seeds:
        start = time.perf_counter()
        if reselected and (out / task / f"s{seed}" / "summary.json").exists():
            record = reselect(
                out / task / f"s{seed}", episodes=episodes, eval_seed=final_seed(seed)
            )
            print(f"{task} seed {seed}: selection {record}", flush=True)
        try:
            result = run_seed(
                str(preset),
                seed,
                out / task / f"s{seed}",
                overrides=overrides,
                env_steps=env_steps,
                episodes=episodes,
                eval_seed=final_seed(seed),
            )
        except subprocess.CalledProcessError:  # reported and left out; the others go on
            print(f"{task} seed {seed}: FAILED, see {out / task / f's{seed}.log'}", flush=True)
            continue
        eval_episodes = int(settings.get("eval_episodes", config.eval_episodes))
        steps, evaluations = read_metric(result.run_dir / "metrics.csv", "eval/return_mean")
        _, guarded = read_metric(result.run_dir / "metrics.csv", "guard/return_mean")
        summary = json.loads((result.run_dir / "summary.json").read_text())
        row = SeedRow(
            seed=seed,
            tree=graft.evaluate(tree, episodes=episodes, seed=final_seed(seed)).mean,
            final=result.mean,
            tree_in_run=graft.evaluate(tree, episodes=eval_episodes, seed=in_run_seed(seed)).mean,
            steps=steps,
            evaluations=evaluations,
            env_steps=int(summary["env_steps"]),
            wall_s=result.wall_s,
            parts=part_scores(result.run_dir, episodes=episodes, seed=final_seed(seed))
            if parts
            else {},
            guarded=guarded,
        )
        rows.append(row)
        print(
            f"{task} seed {seed}: tree {row.tree:.1f}, final {row.final:.1f} "
            f"({row.improvement:+.1f}); worst in-run evaluation "
            f"{100 * worst_drop(row, budget):+.0f} % of |tree| (guarded "
            f"{100 * worst_drop(row, budget, guarded=True):+.0f} %); {row.env_steps} env steps, "
            f"{row.wall_s:.0f} s ({time.perf_counter() - start:.0f} s with scoring)",
            flush=True,
        )
    if not rows:
        raise SystemExit(f"{task}: every seed failed (logs in {out / task})")
    return summarise(task, rows, budget=budget, algorithm=config.algorithm), rows


def summarise(task: str, rows: Sequence[SeedRow], *, budget: int, algorithm: str) -> dict[str, Any]:
    """One task's table row, and whether each target is met."""
    gains = [r.improvement for r in rows]
    stats = summarize(gains)
    drops = [worst_drop(r, budget) for r in rows]
    finite = [d for d in drops if np.isfinite(d)]
    worst = min(finite) if finite else math.nan
    guarded = [d for d in (worst_drop(r, budget, guarded=True) for r in rows) if np.isfinite(d)]
    worst_guarded = min(guarded) if guarded else math.nan
    return {
        "task": task,
        "algorithm": algorithm,
        "seeds": len(rows),
        "tree": float(np.mean([r.tree for r in rows])),
        "finals": [round(r.final, 1) for r in rows],
        "final_mean": float(np.mean([r.final for r in rows])),
        "improvement": stats.mean,
        "improvement_ci": list(stats.mean_ci),
        "improvement_line": stats.line(),
        "seeds_at_least_tree": int(sum(g >= 0 for g in gains)),
        "worst_in_run": worst,
        "worst_in_run_guarded": worst_guarded,
        "env_steps": int(np.mean([r.env_steps for r in rows])),
        "wall_s": float(np.mean([r.wall_s for r in rows])),
        "every_seed_at_least_tree": all(g >= 0 for g in gains),
        "ci_above_zero": len(rows) >= MIN_SEEDS and stats.mean_ci[0] > 0,
        "never_far_below": bool(finite) and worst >= -WORST_DROP,
        "guarded_never_far_below": bool(guarded) and worst_guarded >= -WORST_DROP,
    }


def table(summaries: Sequence[dict[str, Any]]) -> str:
    """The Markdown table the README quotes."""
    lines = [
        "| task | method | env steps | tree | final per seed | improvement, mean [95 % CI] "
        "| seeds ≥ tree | worst in-run eval vs tree | the same, guarded | wall s / run |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        low, high = s["improvement_ci"]
        ci = f" [{low:+.1f}, {high:+.1f}]" if np.isfinite(low) else " (no CI below 3 seeds)"
        lines.append(
            f"| {s['task']} | {s['algorithm']} | {s['env_steps']:,} | {s['tree']:.1f} "
            f"| {', '.join(f'{f:.1f}' for f in s['finals'])} | {s['improvement']:+.1f}{ci} "
            f"| {s['seeds_at_least_tree']}/{s['seeds']} | {_percent(s['worst_in_run'])} "
            f"| {_percent(s['worst_in_run_guarded'])} | {s['wall_s']:.0f} |"
        )
    return "\n".join(lines)


def _percent(fraction: float) -> str:
    return f"{round(100 * fraction) + 0:+d} %" if np.isfinite(fraction) else "-"


def plot(results: dict[str, list[SeedRow]], png: Path, episodes: int) -> None:
    """Per task: the in-run evaluations minus the tree's score on the same episodes, each
    seed thin and their mean thick (`experiments.plots.curves`), the final improvements
    as dots at the end."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(1, len(results), figsize=(4.5 * len(results), 3.8), squeeze=False)
    for ax, (task, rows) in zip(axes[0], results.items(), strict=True):
        points = [
            {"variant": task, "seed": str(r.seed), "env_steps": s, "return_mean": e - r.tree_in_run}
            for r in rows
            for s, e in zip(r.steps, r.evaluations, strict=True)
        ]
        c = curves(points, task)
        for values in c["per_seed"]:
            ax.plot(c["env_steps"], values, color="tab:blue", alpha=0.3, linewidth=0.8)
        ax.plot(c["env_steps"], c["mean"], color="tab:blue", label=f"in-run, {c['seeds']} seeds")
        guarded = [
            {"variant": task, "seed": str(r.seed), "env_steps": s, "return_mean": g - r.tree_in_run}
            for r in rows
            if len(r.guarded) == len(r.steps)
            for s, g in zip(r.steps, r.guarded, strict=True)
        ]
        if guarded:
            g = curves(guarded, task)
            ax.plot(g["env_steps"], g["mean"], color="tab:purple", linewidth=2.0, zorder=4,
                    label="guarded: what a run stopped there plays")  # fmt: skip
        end = max(r.env_steps for r in rows)
        ax.scatter([end] * len(rows), [r.improvement for r in rows], color="tab:orange",
                   zorder=3, label=f"final, {episodes} episodes")  # fmt: skip
        ax.axhline(0.0, color="tab:green", linestyle="--", label="the tree")
        ax.set_title(task)
        ax.xaxis.set_major_locator(MaxNLocator(5))
        ax.set_xlabel("environment steps")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("return minus the tree's")
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)


def main(argv: Optional[Sequence[str]] = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--task", choices=sorted(TASKS))
    which.add_argument("--suite", action="store_true", help="every task")
    which.add_argument(
        "--plot", nargs="+", type=Path, metavar="JSON",
        help="the table and figure of earlier runs from their improve*.json (to --out), no "
        "training; a task's seeds from several files are taken together",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--env-steps", type=int, help="override the task's budget")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-improve"))
    parser.add_argument(
        "--quick", action="store_true", help=f"1 seed, 600 env steps, {QUICK_EPISODES} episodes"
    )
    parser.add_argument("--parts", action="store_true", help="score each acting part too")
    parser.add_argument(
        "--reselect", action="store_true", help="apply the current selection rule to finished runs"
    )
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds {args.seeds}: must be >= 1")
    bad = [o for o in args.set if "=" not in o]
    if bad:
        parser.error(f"--set {bad[0]!r}: expected key=value, e.g. td3.batch_size=128")
    if args.plot:
        return replot(args.plot, args.out / "improve.png")
    if args.quick:
        args.seeds, args.env_steps = 1, args.env_steps or 600
    episodes = QUICK_EPISODES if args.quick else EPISODES
    tasks = sorted(TASKS) if args.suite else [args.task]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    summaries, results = [], {}
    for task in tasks:
        summary, rows = run_task(
            task,
            seeds=seeds,
            out=args.out,
            overrides=args.set,
            env_steps=args.env_steps,
            quick=args.quick,
            episodes=episodes,
            parts=args.parts,
            reselected=args.reselect,
        )
        summaries.append(summary)
        results[task] = rows
        print(summary["improvement_line"], flush=True)
    print()
    print(table(summaries))
    if args.parts:
        print()
        print(
            parts_table(
                {t: [(r.seed, r.tree, r.final, r.parts) for r in rs] for t, rs in results.items()}
            )
        )
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "improve" if args.suite else f"improve-{args.task}"
    (args.out / f"{stem}.json").write_text(
        json.dumps(
            {
                "summaries": summaries,
                "seeds": {t: [asdict(r) for r in rs] for t, rs in results.items()},
            },
            indent=1,
        )
    )
    plot(results, args.out / f"{stem}.png", episodes)
    print(f"\n{args.out / f'{stem}.json'}, {args.out / f'{stem}.png'}")
    return summaries


def replot(saved: Sequence[Path], png: Path) -> list[dict[str, Any]]:
    """The table and figure of earlier runs' improve*.json files, a task's seeds from
    several files (e.g. two benches of different seeds) taken together; their summaries."""
    results: dict[str, list[SeedRow]] = {}
    method: dict[str, tuple[int, str]] = {}
    for path in saved:
        data = json.loads(path.read_text())
        for s in data["summaries"]:
            method[s["task"]] = (round(s["env_steps"]), s["algorithm"])
        for task, rows in data["seeds"].items():
            results.setdefault(task, []).extend(SeedRow(**r) for r in rows)
    summaries = [
        summarise(
            task,
            sorted(rows, key=lambda r: r.seed),
            budget=method[task][0],
            algorithm=method[task][1],
        )  # fmt: skip
        for task, rows in results.items()
    ]
    for summary in summaries:
        print(summary["improvement_line"])
    print(table(summaries))
    plot(results, png, EPISODES)
    print(png)
    return summaries


if __name__ == "__main__":
    main()
