"""Benchmark: does graft's recipe end above both the user's hard-coded policy and RL
without it, and never below the tree?

Each task is a user's own preset (an environment, a tree, a budget, and no algorithm, so
it trains with graft's default recipe). Each task runs two arms: the recipe, and RL from
scratch (graft's own TD3 or Double DQN on the same preset with `algorithm` set and
rl-baselines3-zoo's settings, `SCRATCH`; no tree), with the same env-step budget, seeds
and held-out episodes. Per task, arm and seed, exactly the documented commands, each in
its own process (`bench/seeds.py`):

    graft train --preset TASK.yaml --seed S --run-dir OUT/TASK/ARM/sS [--set ...]
    graft eval --policy OUT/TASK/ARM/sS --episodes 50 --seed 100000+1000·S

and the tree alone on the same 50 episodes (held out: no run resets from them,
`graft.seeds`). It prints one row per task (the tree, from scratch, the recipe, and
the recipe's margin over the better of the tree and from scratch, paired by seed, with its
95 % bootstrap CI over seeds, `bench/improve_report.py`) and each arm's seeds against the
tree; writes OUT/improve*.json (with the commit) and a figure per task,
OUT/improve-TASK.png: return against env steps for the tree, from scratch and the recipe.

    python -m bench.improve --task cartpole --seeds 5 --env-steps 50000
    python -m bench.improve --task pendulum --seeds 5 --env-steps 30000 --arm recipe
    python -m bench.improve --suite --seeds 5
    python -m bench.improve --task pendulum --quick   # a smoke run: 1 seed, 600 steps, 10 episodes
    python -m bench.improve --task lunarlander --seeds 5 --parts   # + each part's share

As the outside reference a user would reach for, `--arm sb3-td3 --arm sb3-sac` (continuous
tasks) or `--arm sb3-dqn` (discrete) runs stable-baselines3 from scratch with
rl-baselines3-zoo's settings (`bench/improve_sb3.py`, a bench-only extra), on the same
budget, seeds and held-out episodes; the task row then shows them and the recipe's margin
over the best of them too:

    python -m bench.improve --task pendulum --arm sb3-td3 --arm sb3-sac --seeds 2 --env-steps 30000

`--set` applies to the recipe arm only; `--scratch-set` adds to from scratch's settings (a
control for a recipe candidate: its change, e.g. a LayerNorm, without the tree). With
``--parts`` each recipe seed's networks are also scored without the final selection and
without switching too, on the same episodes (`bench/improve_parts.py`).

The examples must be installed (``pip install -e examples/mountaincar examples/cartpole
examples/lunarlander examples/halfcheetah``). A seed whose run finished is read back, not
re-run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, Optional

import graft
from bench.improve_parts import part_scores, parts_table, reselect
from bench.improve_report import (
    ARMS,
    REFERENCE_ARMS,
    SeedRow,
    along_budget,
    along_budget_table,
    compare,
    plot_task,
    summarise,
    table,
    task_table,
    worst_drop,
)
from bench.improve_sb3 import HYPERPARAMETERS, require, run_arm
from bench.seeds import REPO, SeedResult, asked, refuse_other_settings, run_seed
from graft.api import Policy
from graft.cli.flags import parse_settings
from graft.config import load_preset
from graft.seeds import LEGACY_EVALUATION, held_out_seed
from service.metrics import read_metric

TASKS = {
    "pendulum": REPO / "bench" / "tasks" / "pendulum.yaml",
    "mountaincar": REPO / "examples" / "mountaincar" / "presets" / "recipe.yaml",
    "cartpole": REPO / "examples" / "cartpole" / "presets" / "recipe.yaml",
    "lunarlander": REPO / "examples" / "lunarlander" / "presets" / "recipe.yaml",
    "lunarlander-discrete": REPO / "examples" / "lunarlander" / "presets" / "recipe-discrete.yaml",
    "halfcheetah": REPO / "examples" / "halfcheetah" / "presets" / "recipe.yaml",
    # Held out: each tree written and scored before any recipe run on it (docs/results.md).
    "acrobot": REPO / "bench" / "tasks" / "acrobot.yaml",
    "reacher": REPO / "examples" / "heldout" / "presets" / "reacher.yaml",
    "hopper": REPO / "examples" / "heldout" / "presets" / "hopper.yaml",
    "walker2d": REPO / "examples" / "heldout" / "presets" / "walker2d.yaml",
}
"""Task name -> a user's preset: environment, hard-coded policy, budget, no algorithm."""
_LAYOUT = ("num_actors=1", "envs_per_actor=4")  # the recipe's actors: only the method differs
_DQN = (*_LAYOUT, "algorithm=ddqn", "dqn.hidden_sizes=[256,256]")
_ZOO_LANDER_DQN = (
    *_DQN,
    "learning_starts=1000",
    "updates_per_env_step=1.0",
    "dqn.learning_rate=0.00063",
    "dqn.batch_size=128",
    "dqn.target_update_every=250",
    "dqn.epsilon_start=1.0",
    "dqn.epsilon_end=0.1",
    "dqn.epsilon_decay_env_steps=3600",
)
"""rl-baselines3-zoo's DQN for LunarLander, which it uses for Acrobot too."""
_TD3 = (*_LAYOUT, "algorithm=td3", "updates_per_env_step=1.0", "td3.hidden_sizes=[256,256]",
        "td3.batch_size=256", "td3.actor_lr=0.001", "td3.critic_lr=0.001")  # fmt: skip
SCRATCH: dict[str, tuple[str, ...]] = {
    # graft's cartpole-ddqn preset (rl-baselines3-zoo's CartPole DQN, made to hold its policy)
    "cartpole": (
        *_DQN,
        "learning_starts=1000",
        "updates_per_env_step=0.5",
        "dqn.learning_rate=0.0023",
        "dqn.learning_rate_end=0.0",
        "dqn.batch_size=128",
        "dqn.n_step=3",
        "dqn.target_update_every=1",
        "dqn.target_tau=0.005",
        "dqn.epsilon_start=1.0",
        "dqn.epsilon_end=0.01",
        "dqn.epsilon_decay_env_steps=8000",
    ),
    # zoo's LunarLander DQN: lr 6.3e-4, batch 128, target every 250 steps, ε → 0.1 over 12 %
    "lunarlander-discrete": _ZOO_LANDER_DQN,
    # zoo's Acrobot DQN: as its LunarLander's (ε → 0.1 over 12 % of 100k: 3,600 of 30k)
    "acrobot": _ZOO_LANDER_DQN,
    # zoo's TD3 (SB3 defaults: lr 1e-3; Pendulum and LunarLanderContinuous: γ 0.98, 10k
    # random steps first; MountainCarContinuous: noise 0.5; HalfCheetah: 10k random steps)
    "pendulum": (*_TD3, "learning_starts=10000", "td3.gamma=0.98", "td3.exploration_noise=0.1"),
    "lunarlander": (
        *_TD3,
        "learning_starts=10000",
        "td3.gamma=0.98",
        "td3.exploration_noise=0.1",
    ),
    "mountaincar": (*_TD3, "learning_starts=1000", "td3.exploration_noise=0.5"),
    "halfcheetah": (*_TD3, "learning_starts=10000", "td3.exploration_noise=0.1"),
    # held out: zoo's MuJoCo TD3 defaults, as HalfCheetah's (zoo has no Reacher entry)
    "reacher": (*_TD3, "learning_starts=10000", "td3.exploration_noise=0.1"),
    "hopper": (*_TD3, "learning_starts=10000", "td3.exploration_noise=0.1"),
    "walker2d": (*_TD3, "learning_starts=10000", "td3.exploration_noise=0.1"),
}
"""Task name -> the from-scratch arm's settings on the task's preset: graft's own Double
DQN or TD3, no tree, 256x256 networks, rl-baselines3-zoo's hyper-parameters for the task
where it has them (its LunarLander DQN's ε decays over 12 % of its 100k steps: 3,600 of a
30k budget). A baseline a user would run, not tuned here."""
EPISODES = 50
"""Final evaluation episodes per seed (the tree's score uses the same ones)."""
QUICK_EPISODES = 10
"""--quick's final evaluation episodes: enough to see the pipeline work, not a result."""
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
    them, `graft.seeds`)."""
    return held_out_seed(seed)


def in_run_seed(summary: dict[str, Any]) -> int:
    """First reset seed of a finished run's in-run evaluations and final selection, as its
    summary.json records it (runs trained before the record: `graft.seeds`' legacy one)."""
    return int(summary.get("evaluation_seed", LEGACY_EVALUATION + summary["seed"]))


def arm_overrides(task: str, arm: str, overrides: Sequence[str], quick: bool) -> list[str]:
    """The `--set`s of one arm: the recipe's are the caller's, from scratch's `SCRATCH` and
    then the caller's; --quick adds its own to the sections the arm's method reads."""
    given = list(overrides) if arm == "recipe" else [*SCRATCH[task], *overrides]
    if not quick:
        return given
    config = load_preset(TASKS[task], **parse_settings(given))
    unused = ("td3.",) if config.algorithm == "ddqn" else ("dqn.",)
    if arm == "scratch":  # no tree: no burn-in on its warm-up, no selection
        unused += ("selection.", "td3.burn_in", "td3.frozen", "dqn.burn_in")
    keys = {o.split("=")[0] for o in overrides}
    extra = [f"{k}={v}" for k, v in QUICK.items() if not k.startswith(unused) and k not in keys]
    return [*given, *extra]


def score_seed(
    result: SeedResult, *, seed: int, tree: Policy, eval_episodes: int, episodes: int, parts: bool
) -> SeedRow:
    """One finished run's row: its final and in-run scores and the tree's on the same
    episodes."""
    steps, evaluations = read_metric(result.run_dir / "metrics.csv", "eval/return_mean")
    _, guarded = read_metric(result.run_dir / "metrics.csv", "guard/return_mean")
    summary = json.loads((result.run_dir / "summary.json").read_text())
    return SeedRow(
        seed=seed,
        tree=graft.evaluate(tree, episodes=episodes, seed=final_seed(seed)).mean,
        final=result.mean,
        tree_in_run=graft.evaluate(tree, episodes=eval_episodes, seed=in_run_seed(summary)).mean,
        steps=steps,
        evaluations=evaluations,
        env_steps=int(summary["env_steps"]),
        wall_s=result.wall_s,
        parts=part_scores(result.run_dir, episodes=episodes, seed=final_seed(seed))
        if parts
        else {},
        guarded=guarded,
    )


def run_task(
    task: str,
    *,
    arm: str = "recipe",
    seeds: Sequence[int],
    out: Path,
    overrides: Sequence[str],
    env_steps: Optional[int],
    quick: bool = False,
    episodes: int = EPISODES,
    parts: bool = False,
    reselected: bool = False,
) -> tuple[dict[str, Any], list[SeedRow]]:
    """Trains and scores every seed of one arm of one task; its summary and seed rows."""
    preset = TASKS[task]
    if arm in REFERENCE_ARMS:  # stable-baselines3, in a process per seed of its own
        in_run = (QUICK["eval_every"], QUICK["eval_episodes"]) if quick else (None, None)
        return run_arm(task, arm, preset=preset, seeds=seeds, out=out, env_steps=env_steps,
                       episodes=episodes, in_run=in_run)  # fmt: skip
    overrides = arm_overrides(task, arm, overrides, quick)
    settings = parse_settings(list(overrides))
    config = load_preset(preset, **settings, **({"env_steps": env_steps} if env_steps else {}))
    tree = graft.load_policy("hardcoded", preset=preset)
    rows: list[SeedRow] = []
    refuse_other_settings({out / task / arm / f"s{s}": asked(str(preset), s, overrides=overrides,
                                                            env_steps=env_steps) for s in seeds},
                          ignoring=("selection.",) if reselected else ())  # fmt: skip
    for seed in seeds:
        start, run_dir = time.perf_counter(), out / task / arm / f"s{seed}"
        if reselected and arm == "recipe" and (run_dir / "summary.json").exists():
            record = reselect(run_dir, rule=config.selection, episodes=episodes,
                              eval_seed=final_seed(seed))  # fmt: skip
            print(f"{task} seed {seed}: selection {record}", flush=True)
        try:
            result = run_seed(
                str(preset),
                seed,
                run_dir,
                overrides=overrides,
                env_steps=env_steps,
                episodes=episodes,
                eval_seed=final_seed(seed),
            )
        except subprocess.CalledProcessError:  # reported and left out; the others go on
            print(f"{task} {arm} seed {seed}: FAILED, see {run_dir}.log", flush=True)
            continue
        row = score_seed(
            result,
            seed=seed,
            tree=tree,
            episodes=episodes,
            eval_episodes=config.eval_episodes,
            parts=parts and arm == "recipe",
        )
        rows.append(row)
        print(
            f"{task} {arm} seed {seed}: tree {row.tree:.1f}, final {row.final:.1f} "
            f"({row.improvement:+.1f}); worst in-run evaluation "
            f"{100 * worst_drop(row, config.env_steps):+.0f} % of |tree|; {row.env_steps} "
            f"env steps, {row.wall_s:.0f} s ({time.perf_counter() - start:.0f} s with scoring)",
            flush=True,
        )
    if not rows:
        raise SystemExit(f"{task} {arm}: every seed failed (logs in {out / task / arm})")
    summary = summarise(task, rows, budget=config.env_steps, algorithm=config.algorithm)
    return {**summary, "arm": arm}, rows


def commit() -> str:
    """The code's commit, '+dirty' when the worktree has changes (each run's own
    summary.json records its provenance too)."""

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True).stdout

    return git("rev-parse", "HEAD").strip() + (
        "+dirty" if git("status", "--porcelain").strip() else ""
    )


def report(
    summaries: Sequence[dict[str, Any]], results: Mapping[str, Mapping[str, list[SeedRow]]],
    out: Path, stem: str, *, code: str, parts: bool = False,
    settings: Optional[Mapping[str, Sequence[str]]] = None,
) -> list[dict[str, Any]]:  # fmt: skip
    """Prints the tables, writes OUT/STEM.json (with `code`, the commit the runs were
    made at, and the `--set`s they ran with, when given) and a figure per task; the task
    rows."""
    tasks = [compare(task, arms) for task, arms in results.items()]
    print()
    print(task_table(tasks))
    print()
    print(table(summaries))
    if along := {t: points for t, arms in results.items() if (points := along_budget(arms))}:
        print("\nIn-run evaluations along the budget (the same episodes for both arms):\n")
        print(along_budget_table(along))
    if parts:
        recipe = {t: arms["recipe"] for t, arms in results.items() if "recipe" in arms}
        print()
        print(parts_table({t: [(r.seed, r.tree, r.final, r.parts) for r in rs]
                           for t, rs in recipe.items()}))  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    saved = {
        "commit": code,
        "tasks": tasks,
        "along_budget": along,
        "summaries": list(summaries),
        "seeds": {t: {a: [asdict(r) for r in rs] for a, rs in arms.items()}
                  for t, arms in results.items()},
    }  # fmt: skip
    if settings is not None:
        saved["settings"] = dict(settings)
    (out / f"{stem}.json").write_text(json.dumps(saved, indent=1))
    for task, arms in results.items():
        plot_task(task, arms, out / f"improve-{task}.png")
    print(f"\n{out / f'{stem}.json'}, {', '.join(f'improve-{t}.png' for t in results)}")
    return tasks


def main(argv: Optional[Sequence[str]] = None) -> list[dict[str, Any]]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--task", choices=sorted(TASKS))
    which.add_argument("--suite", action="store_true", help="every task")
    which.add_argument(
        "--plot", nargs="+", type=Path, metavar="JSON",
        help="the tables and figures of earlier runs from their improve*.json (to --out), no "
        "training; a task's seeds from several files are taken together (a seed in two: the "
        "later file's), a row per task and budget",
    )  # fmt: skip
    parser.add_argument(
        "--arm", action="append", choices=(*ARMS, *REFERENCE_ARMS),
        help=f"default: graft's arms ({', '.join(ARMS)}); the stable-baselines3 ones "
        "(bench/improve_sb3.py) only when named",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--env-steps", type=int, help="override the task's budget")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a recipe setting (the recipe arm only)")  # fmt: skip
    parser.add_argument("--scratch-set", action="append", default=[], metavar="KEY=VALUE",
                        help="added to from scratch's settings (the scratch arm only)")  # fmt: skip
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
    for flag, given in (("--set", args.set), ("--scratch-set", args.scratch_set)):
        if bad := [o for o in given if "=" not in o]:
            parser.error(f"{flag} {bad[0]!r}: expected key=value, e.g. td3.batch_size=128")
    if args.plot:
        return replot(args.plot, args.out)
    if args.quick:
        args.seeds, args.env_steps = 1, args.env_steps or 600
    tasks = sorted(TASKS) if args.suite else [args.task]
    arms = args.arm or ARMS
    if any(a in REFERENCE_ARMS for a in arms):
        if args.task and (bad := [a for a in arms if a in REFERENCE_ARMS
                                  and (args.task, a) not in HYPERPARAMETERS]):  # fmt: skip
            parser.error(f"--arm {bad[0]}: not for task {args.task} (continuous tasks take "
                         "sb3-td3 and sb3-sac, discrete ones sb3-dqn)")  # fmt: skip
        require()
    summaries, results = [], {}
    for task in tasks:
        for arm in [a for a in arms if a not in REFERENCE_ARMS or (task, a) in HYPERPARAMETERS]:
            summary, rows = run_task(
                task, arm=arm, seeds=range(args.first_seed, args.first_seed + args.seeds),
                out=args.out, overrides=args.scratch_set if arm == "scratch" else args.set,
                env_steps=args.env_steps, quick=args.quick,
                episodes=QUICK_EPISODES if args.quick else EPISODES, parts=args.parts,
                reselected=args.reselect,
            )  # fmt: skip
            summaries.append(summary)
            results.setdefault(task, {})[arm] = rows
            print(f"{task} {arm}: {summary['improvement_line']}", flush=True)
    stem = "improve" if args.suite else f"improve-{args.task}"
    settings = {"set": args.set, "scratch_set": args.scratch_set}
    return report(
        summaries, results, args.out, stem, code=commit(), parts=args.parts, settings=settings
    )


def budget_of(env_steps: float) -> int:
    """The budget a run was given, from the env steps it ran: rounded down to two
    significant digits (a run stops at the first vector step or episode end past its budget:
    LunarLander's 30,000 ends at 30,648, CartPole's 50,000 at 50,176)."""
    steps = int(env_steps)
    unit = 10 ** max(len(str(steps)) - 2, 0)
    return steps // unit * unit


Gathered = dict[tuple[str, int], dict[str, dict[int, tuple[SeedRow, Path]]]]
"""(task, budget) -> arm -> seed -> (its row, the file it came from)."""


def gather(saved: Sequence[Path]) -> tuple[Gathered, dict[tuple[str, int, str], str], list[str]]:
    """The seeds of earlier runs' improve*.json files, by task, budget and arm; the
    algorithm of each; the files' commits. A seed in two files is taken from the later one
    on the command line (a re-scored run), and a line says so when the two differ."""
    runs: Gathered = {}
    algorithms: dict[tuple[str, int, str], str] = {}
    commits: list[str] = []
    for path in saved:
        data = json.loads(path.read_text())
        commits.append(data.get("commit", "unrecorded"))
        given = {(s["task"], s.get("arm", "recipe")): s for s in data["summaries"]}
        for task, arms in data["seeds"].items():
            arms = arms if isinstance(arms, dict) else {"recipe": arms}  # before the arms
            for arm, rows in arms.items():
                budget = budget_of(given[(task, arm)]["env_steps"])
                name = probe_name(arm, data.get("settings", {}))
                algorithms[(task, budget, name)] = given[(task, arm)]["algorithm"]
                kept = runs.setdefault((task, budget), {}).setdefault(name, {})
                for row in (SeedRow(**r) for r in rows):
                    _replace(kept, row, path, f"{task} {arm} seed {row.seed} at {budget:,}")
    return runs, algorithms, commits


def probe_name(arm: str, settings: Mapping[str, Sequence[str]]) -> str:
    """An arm's name in the tables: one run with `--set`s (the recipe's) or `--scratch-set`s
    is a probe beside the arm, named by them, never pooled with the arm's own seeds."""
    given = settings.get({"recipe": "set", "scratch": "scratch_set"}.get(arm, ""), [])
    return f"{arm} [{', '.join(given)}]" if given else arm


def _replace(kept: dict[int, tuple[SeedRow, Path]], row: SeedRow, path: Path, what: str) -> None:
    """Keeps `row` (from `path`) for its seed, saying so when it differs from one kept."""
    if row.seed in kept and kept[row.seed][0] != row:
        old, source = kept[row.seed]
        print(f"{what} env steps: {path}'s ({row.final:.1f}) replaces {source}'s ({old.final:.1f})")
    kept[row.seed] = (row, path)


def replot(saved: Sequence[Path], out: Path) -> list[dict[str, Any]]:
    """The tables and figures of earlier runs' improve*.json files (`gather`), a task's
    arm's seeds from several files (e.g. two benches of different seeds) taken together (a
    file written before the arms existed holds the recipe's seeds); the task rows. A task
    run at more than one budget gets a row per budget, named TASK-BUDGET (halfcheetah-30k)."""
    runs, algorithms, commits = gather(saved)
    budgets: dict[str, list[int]] = {}
    for task, budget in runs:
        budgets.setdefault(task, []).append(budget)
    results: dict[str, dict[str, list[SeedRow]]] = {}
    summaries = []
    for (task, budget), arms in sorted(runs.items()):
        name = task if len(budgets[task]) == 1 else f"{task}-{budget_label(budget)}"
        for arm, kept in arms.items():
            rows = [kept[seed][0] for seed in sorted(kept)]
            algorithm = algorithms[(task, budget, arm)]
            summary = summarise(name, rows, budget=budget, algorithm=algorithm)
            summaries.append({**summary, "arm": arm})
            results.setdefault(name, {})[arm] = rows
            print(f"{name} {arm}: {summary['improvement_line']}")
    return report(summaries, results, out, "improve", code=", ".join(dict.fromkeys(commits)))


def budget_label(budget: int) -> str:
    """30000 -> '30k'; a budget not in whole thousands as it is."""
    return f"{budget // 1000}k" if budget % 1000 == 0 else str(budget)


if __name__ == "__main__":
    main()
