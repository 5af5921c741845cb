"""bench/improve.py's figures: each arm's summary, the task table (tree, from scratch,
recipe, the recipe's margin over the better of the two), and a figure per task.

Every comparison pairs seeds: seed S of every arm and the tree are scored on the same
held-out episodes (`graft.seeds.held_out_seed`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from graft.experiments.stats import MIN_SEEDS, bootstrap_ci, summarize

BURN_IN_FRACTION = 0.1
"""In-run evaluations before this fraction of the budget are not held to the tree."""
WORST_DROP = 0.1
"""Target: no in-run evaluation (after the first tenth) below the tree by more than this
fraction of the tree's |score|."""
ARMS = ("scratch", "recipe")
"""The arms a task runs by default: RL without the tree (graft's own TD3 or Double DQN),
and graft's default recipe with the tree."""
REFERENCE_ARMS = {"sb3-td3": "SB3 TD3", "sb3-sac": "SB3 SAC", "sb3-dqn": "SB3 DQN"}
"""The outside reference, on request (`--arm`): stable-baselines3 from scratch
(`bench/improve_sb3.py`), and each one's short name."""


def mean_ci(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """95 % percentile-bootstrap interval of the mean (NaN below `MIN_SEEDS` values)."""
    return bootstrap_ci(values, np.mean)


ARM_LABELS = {
    "scratch": "from scratch (graft)",
    "recipe": "recipe",
    "tree": "tree",
    **{arm: f"from scratch ({name})" for arm, name in REFERENCE_ARMS.items()},
}


@dataclass(frozen=True)
class SeedRow:
    """One seed of one arm of one task."""

    seed: int
    tree: float
    """The tree's mean return on this seed's final (held-out) episodes."""
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


def summarise(task: str, rows: Sequence[SeedRow], *, budget: int, algorithm: str) -> dict[str, Any]:
    """One arm's row on one task, and whether each of its targets is met. A seed counts as
    improved only when its final is strictly above the tree's score: a run whose selection
    kept the tree ties it and is not counted."""
    gains = [r.improvement for r in rows]
    stats = summarize(gains)
    drops = [worst_drop(r, budget) for r in rows]
    finite = [d for d in drops if np.isfinite(d)]
    worst = min(finite) if finite else math.nan
    guarded = [d for d in (worst_drop(r, budget, guarded=True) for r in rows) if np.isfinite(d)]
    return {
        "task": task,
        "algorithm": algorithm,
        "seeds": len(rows),
        "seed_list": [r.seed for r in rows],
        "tree": float(np.mean([r.tree for r in rows])),
        "finals": [round(r.final, 1) for r in rows],
        "final_mean": float(np.mean([r.final for r in rows])),
        "final_ci": list(summarize([r.final for r in rows]).mean_ci),
        "improvement": stats.mean,
        "improvement_ci": list(stats.mean_ci),
        "improvement_line": stats.line(),
        "seeds_above_tree": int(sum(g > 0 for g in gains)),
        "worst_in_run": worst,
        # A diagnostic, never a target: the tree's own score whenever the selection kept
        # the tree, judged on the same episodes, so it cannot fall below 0 on those.
        "worst_in_run_guarded": min(guarded) if guarded else math.nan,
        "env_steps": int(np.mean([r.env_steps for r in rows])),
        "wall_s": float(np.mean([r.wall_s for r in rows])),
        "every_seed_above_tree": all(g > 0 for g in gains),
        "ci_above_zero": len(rows) >= MIN_SEEDS and stats.mean_ci[0] > 0,
        "never_far_below": bool(finite) and worst >= -WORST_DROP,
    }


def compare(task: str, arms: Mapping[str, Sequence[SeedRow]]) -> dict[str, Any]:
    """The task's row: the tree, each arm's mean final with its 95 % CI over seeds, and
    the recipe's margin over the better (by mean) of the tree and from-scratch, paired by
    seed on the same held-out episodes, with its 95 % bootstrap CI over seeds."""
    by_seed = {arm: {r.seed: r for r in rows} for arm, rows in arms.items()}
    tree = {s: r.tree for rows in by_seed.values() for s, r in rows.items()}
    row: dict[str, Any] = {"task": task, "tree": float(np.mean(list(tree.values())))}
    for arm, rows in by_seed.items():
        finals = [r.final for r in rows.values()]
        row[arm] = {
            "mean": float(np.mean(finals)),
            "ci": list(mean_ci(finals)),
            "seeds": sorted(rows),
            "env_steps": max(r.env_steps for r in rows.values()),
        }
    recipe, scratch = by_seed.get("recipe", {}), by_seed.get("scratch", {})
    better = "tree"
    if scratch and float(np.mean([r.final for r in scratch.values()])) > row["tree"]:
        better = "scratch"
    paired = sorted(set(recipe) & set(scratch) if better == "scratch" else recipe)
    base = {s: scratch[s].final if better == "scratch" else tree[s] for s in paired}
    margins = [recipe[s].final - base[s] for s in paired]
    row["better"] = better
    row["margin"] = float(np.mean(margins)) if margins else math.nan
    row["margin_ci"] = list(mean_ci(margins)) if margins else [math.nan, math.nan]
    row["margin_seeds"] = paired
    row["recipe_seeds_above_tree"] = sum(recipe[s].final > tree[s] for s in recipe)
    # Where from-scratch beats the tree, a recipe seed ending at or below the tree misses.
    row["recipe_at_or_below_tree_where_scratch_wins"] = sum(
        recipe[s].final <= tree[s] for s in recipe if s in scratch and scratch[s].final > tree[s]
    )
    row["margin_met"] = bool(margins) and row["margin"] >= 0
    return row | reference_margin(by_seed)


def reference_margin(by_seed: Mapping[str, Mapping[int, SeedRow]]) -> dict[str, Any]:
    """The recipe's margin over the best (by mean) stable-baselines3 arm, paired by seed on
    the same held-out episodes, with its 95 % bootstrap CI over seeds (NaN below
    `MIN_SEEDS` paired seeds); empty when no such arm ran."""
    present = {a: rows for a, rows in by_seed.items() if a in REFERENCE_ARMS and rows}
    if not present:
        return {}
    best = max(present, key=lambda a: float(np.mean([r.final for r in present[a].values()])))
    recipe = by_seed.get("recipe", {})
    paired = sorted(set(recipe) & set(present[best]))
    margins = [recipe[s].final - present[best][s].final for s in paired]
    return {
        "best_reference": best,
        "reference_margin": float(np.mean(margins)) if margins else math.nan,
        "reference_margin_ci": list(mean_ci(margins)) if margins else [math.nan, math.nan],
        "reference_margin_seeds": paired,
    }


def along_budget(arms: Mapping[str, Sequence[SeedRow]]) -> list[dict[str, Any]]:
    """Where along the budget the recipe leads: at each env-step count (to the nearest
    thousand) where every seed of both evaluated, the recipe's in-run evaluation minus
    from scratch's, paired by seed (the same in-run episodes), with its 95 % bootstrap CI
    over seeds; empty without both arms."""

    def by_thousand(row: SeedRow) -> dict[int, float]:
        return {round(s / 1000) * 1000: e for s, e in zip(row.steps, row.evaluations, strict=True)}

    recipe = {r.seed: by_thousand(r) for r in arms.get("recipe", [])}
    scratch = {r.seed: by_thousand(r) for r in arms.get("scratch", [])}
    seeds = sorted(set(recipe) & set(scratch))
    if not seeds:
        return []
    common = set.intersection(*(set(recipe[s]) & set(scratch[s]) for s in seeds))
    points = []
    for step in sorted(common):
        lead = [recipe[s][step] - scratch[s][step] for s in seeds]
        points.append({
            "env_steps": step,
            "scratch": float(np.mean([scratch[s][step] for s in seeds])),
            "recipe": float(np.mean([recipe[s][step] for s in seeds])),
            "lead": float(np.mean(lead)),
            "lead_ci": list(mean_ci(lead)),
            "seeds": seeds,
        })  # fmt: skip
    return points


def along_budget_table(tasks: Mapping[str, Sequence[Mapping[str, Any]]]) -> str:
    """`along_budget`'s points of each task, a row each."""
    lines = [
        "| task | env steps | from scratch (graft), in-run | recipe, in-run "
        "| recipe − from scratch, paired [95 % CI] (seeds) |",
        "|---|---|---|---|---|",
    ]
    for task, points in tasks.items():
        for p in points:
            lines.append(
                f"| {task} | {p['env_steps']:,} | {p['scratch']:.1f} | {p['recipe']:.1f} "
                f"| {p['lead']:+.1f}{_signed_ci(p['lead_ci'], '')} ({len(p['seeds'])}) |"
            )
    return "\n".join(lines)


def _signed_ci(ci: Sequence[float], missing: str = " (no CI below 3 seeds)") -> str:
    """' [+low, +high]' of a difference's interval, `missing` where there is none."""
    low, high = ci
    return f" [{low:+.1f}, {high:+.1f}]" if np.isfinite(low) else missing


def _mean_ci(value: Mapping[str, Any]) -> str:
    low, high = value["ci"]
    ci = f" [{low:.1f}, {high:.1f}]" if np.isfinite(low) else ""
    return f"{value['mean']:.1f}{ci} ({len(value['seeds'])})"


def _margin(t: Mapping[str, Any], key: str, seeds: Sequence[int]) -> str:
    """'+M [low, high]' of a paired margin, '(no CI below 3 seeds)' without an interval,
    '-' with no paired seed."""
    if not seeds:
        return "-"
    ci = _signed_ci(t[f"{key}_ci"])
    return f"{t[key]:+.1f}{ci}"


def task_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """One row per task: the tree, each arm (the stable-baselines3 ones in one cell), the
    recipe's margin over the better of the tree and graft's from scratch, and over the
    best stable-baselines3 arm."""
    lines = [
        "| task | env steps | tree | from scratch (graft), mean [95 % CI] (seeds) "
        "| from scratch (SB3), mean [95 % CI] (seeds) | recipe, mean [95 % CI] (seeds) "
        "| recipe − better of tree and from scratch (graft) [95 % CI] "
        "| recipe seeds > tree | recipe − best SB3 arm [95 % CI] |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in rows:
        steps = max(t[a]["env_steps"] for a in (*ARMS, *REFERENCE_ARMS) if a in t)
        margin = _margin(t, "margin", t["margin_seeds"])
        margin += f" vs {ARM_LABELS[t['better']]}" if t["margin_seeds"] else ""
        sb3 = [f"{REFERENCE_ARMS[a]} {_mean_ci(t[a])}" for a in REFERENCE_ARMS if a in t]
        reference = _margin(t, "reference_margin", t.get("reference_margin_seeds", []))
        if "best_reference" in t and t["reference_margin_seeds"]:
            reference += f" vs {REFERENCE_ARMS[t['best_reference']]}"
        recipe_seeds = len(t["recipe"]["seeds"]) if "recipe" in t else 0
        cells = [
            _mean_ci(t["scratch"]) if "scratch" in t else "-",
            "; ".join(sb3) or "-",
            _mean_ci(t["recipe"]) if "recipe" in t else "-",
            margin,
            f"{t['recipe_seeds_above_tree']}/{recipe_seeds}",
            reference,
        ]
        lines.append(f"| {t['task']} | {steps:,} | {t['tree']:.1f} | {' | '.join(cells)} |")
    return "\n".join(lines)


def table(summaries: Sequence[Mapping[str, Any]]) -> str:
    """Each arm's seeds against the tree. The guarded column is a diagnostic with a floor
    by construction (the tree's own score wherever the selection kept the tree)."""
    lines = [
        "| task | method | env steps | tree | final per seed | improvement, mean [95 % CI] "
        "| seeds > tree | worst in-run eval vs tree | guarded (a floor by construction) "
        "| wall s / run |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        ci = _signed_ci(s["improvement_ci"])
        lines.append(
            f"| {s['task']} | {s.get('arm', 'recipe')}: {s['algorithm']} | {s['env_steps']:,} "
            f"| {s['tree']:.1f} "
            f"| {', '.join(f'{f:.1f}' for f in s['finals'])} | {s['improvement']:+.1f}{ci} "
            f"| {s['seeds_above_tree']}/{s['seeds']} | {_percent(s['worst_in_run'])} "
            f"| {_percent(s['worst_in_run_guarded'])} | {s['wall_s']:.0f} |"
        )
    return "\n".join(lines)


def _percent(fraction: float) -> str:
    return f"{round(100 * fraction) + 0:+d} %" if np.isfinite(fraction) else "-"


def band(rows: Sequence[SeedRow]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Env steps, mean and 95 % bootstrap band over seeds of the in-run evaluations, point
    by point (seeds evaluate at slightly different counts: grouped by order)."""
    n = min(len(r.evaluations) for r in rows)
    steps = np.array([[r.steps[i] for i in range(n)] for r in rows], dtype=float).mean(axis=0)
    values = np.array([r.evaluations[:n] for r in rows], dtype=float)
    cis = [mean_ci(values[:, i]) for i in range(n)] if len(rows) >= MIN_SEEDS else []
    low = np.array([c[0] for c in cis]) if cis else values.min(axis=0)
    high = np.array([c[1] for c in cis]) if cis else values.max(axis=0)
    return steps, values.mean(axis=0), low, high


COLOURS = {
    "scratch": "tab:red",
    "recipe": "tab:blue",
    "sb3-td3": "tab:orange",
    "sb3-sac": "tab:purple",
    "sb3-dqn": "tab:brown",
}
SPARE_COLOURS = ("tab:cyan", "tab:olive", "tab:pink", "tab:gray")
"""For arms of other names (candidates beside the recipe), one each in turn."""


def plot_task(task: str, arms: Mapping[str, Sequence[SeedRow]], png: Path) -> None:
    """Return against env steps: the tree (flat, its score on the in-run episodes), from
    scratch and the recipe (in-run evaluations), mean and 95 % band over seeds (below 3
    seeds: their range)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    trees = [r.tree_in_run for rows in arms.values() for r in rows]
    ax.axhline(float(np.mean(trees)), color="tab:green", linestyle="--", label="tree")
    spare = itertools.cycle(SPARE_COLOURS)
    for arm, rows in arms.items():
        steps, mean, low, high = band(rows)
        colour = COLOURS[arm] if arm in COLOURS else next(spare)
        label = f"{ARM_LABELS.get(arm, arm)}, {len(rows)} seeds"
        ax.plot(steps, mean, color=colour, label=label)
        ax.fill_between(steps, low, high, color=colour, alpha=0.2, linewidth=0)
    ax.set_title(f"{task}: in-run evaluations, mean and 95 % band over seeds")
    ax.title.set_fontsize(9)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("return")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=120)
    plt.close(fig)
