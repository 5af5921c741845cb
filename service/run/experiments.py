"""The paper's figures as experiments: presets × variants × seeds, run in parallel on Ray.

    graft experiment fig4 --seeds 10
      └─ one Ray task per (variant, seed): a whole `train` run (its own replay server,
         actors, evaluator and learner), at most --parallel at a time
      └─ runs/experiments/fig4/{results.csv, fig4.png, <variant>-s<seed>/}

Variants are data (a preset plus overrides), like presets themselves.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray

HARD_CODED_LEVEL = -429.0
"""The hard-coded Pendulum policy, `graft eval --policy hardcoded` (100 episodes)."""


@dataclass(frozen=True)
class Variant:
    """One line of a figure: a preset and the overrides that make it this variant."""

    label: str
    preset: str
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Experiment:
    """A figure: its variants, what is plotted and the budget every variant shares."""

    name: str
    title: str
    variants: tuple[Variant, ...]
    final_only: bool = False
    """Plot the last evaluation per variant (fig. 2) instead of curves over env steps."""
    shared: dict[str, Any] = field(default_factory=dict)
    """Overrides applied to every variant (before its own)."""


_DEMO_NOISES = (0.1, 0.5, 1.0, 2.0)
_PAPER_BACKBONE = {
    "learning_starts": 1000,
    "td3.burn_in_updates": 0,
    "td3.frozen_actor_updates": 0,
    "backbone.correction_limit": 2.0,
    "backbone.prefill_noise": 0.5,
    "backbone.observe_backbone": False,
    "td3.exploration_noise": 0.1,
}
EXPERIMENTS = {
    "fig2": Experiment(
        "fig2",
        "Fig. 2: TD3 fully offline on 10k hard-coded transitions, 20k updates",
        tuple(
            Variant(f"offline TD3, σ={s}", "pendulum-offline-td3", {"pretrain.demo_noise": s})
            for s in _DEMO_NOISES
        )
        + tuple(
            Variant(
                f"offline TD3+BC, σ={s}",
                "pendulum-offline-td3",
                {"pretrain.demo_noise": s, "pretrain.pretrain_loss": "td3_bc"},
            )
            for s in _DEMO_NOISES
        ),
        final_only=True,
    ),
    "fig3": Experiment(
        "fig3",
        "Fig. 3: TD3 from scratch vs pre-trained (eqs. 8-9), frozen actor, TD3+BC, burn-in",
        (
            Variant("TD3 from scratch", "pendulum-td3"),
            Variant("pre-trained", "pendulum-pretrained-td3"),
            Variant(
                "pre-trained, actor frozen 5k",
                "pendulum-pretrained-td3",
                {"td3.frozen_actor_updates": 5000},
            ),
            Variant("TD3+BC", "pendulum-td3bc"),
            Variant("critic burn-in", "pendulum-burnin"),
        ),
    ),
    "fig4": Experiment(
        "fig4",
        "Fig. 4: TD3 vs TD3 with the hard-coded policy as backbone (clip range L)",
        (
            Variant("TD3", "pendulum-td3"),
            # Control for the backbone's burn-in: TD3 with the same extra updates at 2k steps.
            Variant(
                "TD3 + burn-in",
                "pendulum-td3",
                {"learning_starts": 2000, "td3.burn_in_updates": 4000},
            ),
            # The preset's recipe (μ(s) observed, wide prefill, critic burn-in) over clip
            # ranges L. With a bang-bang backbone (μ = ±2) only L >= 4 lets a = clip(μ + c)
            # reach every torque in [-2, 2]; narrower ranges keep the action on μ's side.
            *(
                Variant(
                    f"backbone L={limit}", "pendulum-backbone", {"backbone.correction_limit": limit}
                )
                for limit in (4.0, 2.0, 1.0)
            ),
            # The paper's own setting: π(s) sees s only, 1,000 prefill steps of σ = 0.5,
            # no burn-in.
            Variant("backbone (paper) L=2.0", "pendulum-backbone", _PAPER_BACKBONE),
        ),
    ),
    "fig5": Experiment(
        "fig5",
        "Figs. 5-6: hierarchical options {hard-coded, RL}, k = 10, Retrace",
        (Variant("options", "pendulum-options"),),
    ),
}


@ray.remote(num_cpus=0.25)
def _run_one(preset: str, overrides: dict[str, Any], run_dir: str, address: str) -> dict[str, Any]:
    """One seed of one variant: a full `train` run inside a Ray task."""
    import torch

    from service.run.config import load_preset
    from service.run.launcher import train

    torch.set_num_threads(1)
    result = train(
        load_preset(preset, **overrides), run_dir=Path(run_dir), progress=False, address=address
    )
    return {"summary": result.summary, "evaluations": result.evaluations}


def run_experiment(
    name: str,
    *,
    seeds: int,
    out_dir: Path,
    parallel: int = 2,
    overrides: Optional[dict[str, Any]] = None,
    address: str = "local",
    only: Optional[list[str]] = None,
) -> tuple[Path, Path]:
    """Runs every variant × seed, writes results.csv and <name>.png; returns their paths.

    With `only` (variant labels) just those variants run; the rows of the others already
    in results.csv are kept, so a figure can be filled in over several invocations.

    Raises:
        ValueError: unknown experiment, or a variant's preset refuses the overrides.
    """
    from service.run.config import load_preset

    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose from {sorted(EXPERIMENTS)}")
    if seeds < 1 or parallel < 1:
        raise ValueError(f"seeds={seeds} and parallel={parallel} must be >= 1")
    exp = EXPERIMENTS[name]
    labels = [v.label for v in exp.variants]
    unknown = sorted(set(only or []) - set(labels))
    if unknown:
        raise ValueError(f"{name} has no variant(s) {unknown}; its variants: {labels}")
    chosen = [v for v in exp.variants if not only or v.label in only]
    folder = out_dir / name
    folder.mkdir(parents=True, exist_ok=True)
    csv_path = folder / "results.csv"
    kept = [
        r
        for r in (read_rows(csv_path) if csv_path.exists() else [])
        if r["variant"] not in {v.label for v in chosen}
    ]
    jobs = []
    # Seed-major: an experiment cut short still has every variant on the same seeds.
    for seed in range(seeds):
        for variant in chosen:
            merged = {**exp.shared, **variant.overrides, **(overrides or {}), "seed": seed}
            load_preset(variant.preset, **merged)  # refuse bad settings before any run starts
            jobs.append((variant, seed, merged, folder / f"{_slug(variant)}-s{seed}"))
    rows: list[dict[str, Any]] = list(kept)
    pending: dict[Any, tuple[Variant, int]] = {}
    queue, start = list(jobs), time.perf_counter()
    while queue or pending:
        while queue and len(pending) < parallel:
            variant, seed, merged, run_dir = queue.pop(0)
            ref = _run_one.remote(variant.preset, merged, str(run_dir), address)
            pending[ref] = (variant, seed)
        done, _ = ray.wait(list(pending), num_returns=1)
        variant, seed = pending.pop(done[0])
        result = ray.get(done[0])
        for e in result["evaluations"]:
            rows.append(
                {
                    "experiment": name,
                    "variant": variant.label,
                    "seed": seed,
                    "env_steps": e["tag"]["env_steps"],
                    "updates": e["tag"]["updates"],
                    "return_mean": e["mean"],
                    "return_std": e["std"],
                    **{k: v for k, v in e.get("stats", {}).items()},
                }
            )
        print(
            f"[{time.perf_counter() - start:6.0f}s] {variant.label} seed {seed}: final "
            f"{result['summary']['final_eval_return_mean']:.1f} after "
            f"{result['summary']['env_steps']} env steps",
            flush=True,
        )
        write_rows(csv_path, rows)  # after every run: an interrupted experiment keeps them
    return report(name, out_dir)


def _slug(variant: Variant) -> str:
    return variant.label.replace(" ", "_").replace(",", "").replace("=", "")


def rows_from_runs(name: str, folder: Path) -> list[dict[str, Any]]:
    """Evaluation rows rebuilt from the run folders' metrics.csv (an interrupted experiment)."""
    from service.metrics import read_metric

    rows: list[dict[str, Any]] = []
    for variant in EXPERIMENTS[name].variants:
        for run in sorted(folder.glob(f"{_slug(variant)}-s*")):
            if not (run / "summary.json").exists():
                continue  # unfinished
            steps, means = read_metric(run / "metrics.csv", "eval/return_mean")
            _, stds = read_metric(run / "metrics.csv", "eval/return_std")
            for step, mean, std in zip(steps, means, stds, strict=True):
                rows.append(
                    {
                        "experiment": name,
                        "variant": variant.label,
                        "seed": int(run.name.rsplit("-s", 1)[1]),
                        "env_steps": step,
                        "return_mean": mean,
                        "return_std": std,
                    }
                )
    return rows


def report(name: str, out_dir: Path) -> tuple[Path, Path]:
    """Draws <name>.png and writes summary.csv from an experiment's results.csv (rebuilt
    from its finished run folders if the experiment was interrupted before writing it)."""
    exp, folder = EXPERIMENTS[name], out_dir / name
    csv_path, png_path = folder / "results.csv", folder / f"{name}.png"
    if not csv_path.exists():
        write_rows(csv_path, rows_from_runs(name, folder))
    plot_experiment(csv_path, png_path, exp)
    summary = summarise(read_rows(csv_path), [v.label for v in exp.variants])
    write_rows(folder / "summary.csv", summary)
    for row in summary:
        print(", ".join(f"{k}={v}" for k, v in row.items()))
    return csv_path, png_path


def summarise(
    rows: list[dict[str, str]], labels: list[str], *, threshold: float = -200.0, at: int = 5000
) -> list[dict[str, Any]]:
    """Per variant: seeds, final return (mean ± std over seeds), the first env-step count
    at which the across-seed mean reaches `threshold`, and the across-seed std at the
    evaluation nearest `at` env steps."""
    out = []
    for label in labels:
        c = curves(rows, label)
        if not c["seeds"]:
            continue
        finals = c["per_seed"][:, -1]
        reached = np.flatnonzero(c["mean"] >= threshold)
        near = int(np.argmin(np.abs(c["env_steps"] - at)))
        out.append(
            {
                "variant": label,
                "seeds": c["seeds"],
                "final_env_steps": int(c["env_steps"][-1]),
                "final_mean": round(float(finals.mean()), 1),
                "final_std": round(float(finals.std()), 1),
                f"env_steps_to_{int(threshold)}": int(c["env_steps"][reached[0]])
                if len(reached)
                else None,
                f"std_at_{at}": round(float(c["std"][near]), 1),
            }
        )
    return out


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """One CSV with every evaluation of every run (long format)."""
    fields: list[str] = []
    for row in rows:
        fields += [k for k in row if k not in fields]
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def curves(rows: list[dict[str, str]], variant: str, key: str = "return_mean") -> dict[str, Any]:
    """Across-seed mean and std of `key` per evaluation point (by env steps) of one variant.

    Seeds evaluate at slightly different env-step counts (the learner evaluates when it
    sees a multiple of eval_every): points are grouped by their order within each seed.
    """
    by_seed: dict[str, dict[int, float]] = {}
    for r in rows:
        if r["variant"] == variant and r.get(key, "") != "":
            # The final evaluation can share its env-step count with the last periodic
            # one: keep the later (final) value.
            by_seed.setdefault(r["seed"], {})[int(r["env_steps"])] = float(r[key])
    series = [sorted(points.items()) for points in by_seed.values()]
    n = min(len(s) for s in series) if series else 0
    steps = np.array([[s[i][0] for i in range(n)] for s in series], dtype=float)
    values = np.array([[s[i][1] for i in range(n)] for s in series], dtype=float)
    return {
        "env_steps": steps.mean(axis=0) if n else np.zeros(0),
        "mean": values.mean(axis=0) if n else np.zeros(0),
        "std": values.std(axis=0) if n else np.zeros(0),
        "seeds": len(series),
        "per_seed": values,
    }


def plot_experiment(csv_path: Path, png_path: Path, exp: Experiment) -> None:
    """Mean ± std across seeds per variant, with the hard-coded policy's level as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_rows(csv_path)
    labels = [v.label for v in exp.variants if any(r["variant"] == v.label for r in rows)]
    with_usage = any(r.get("options/rl_fraction") for r in rows)
    fig, axes = plt.subplots(1, 2 if with_usage else 1, figsize=(11 if with_usage else 7, 4.5))
    ax = axes[0] if with_usage else axes
    for i, label in enumerate(labels):
        c = curves(rows, label)
        if exp.final_only:
            ax.errorbar([i], [c["mean"][-1]], yerr=[c["std"][-1]], fmt="o", capsize=5)
        else:
            (line,) = ax.plot(c["env_steps"], c["mean"], label=f"{label} ({c['seeds']} seeds)")
            ax.fill_between(
                c["env_steps"],
                c["mean"] - c["std"],
                c["mean"] + c["std"],
                alpha=0.2,
                color=line.get_color(),
            )
    ax.axhline(HARD_CODED_LEVEL, color="tab:green", linestyle="--", label="hard-coded policy")
    if exp.final_only:
        ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("evaluation return (100 episodes)")
    else:
        ax.set_xlabel("environment steps")
        ax.set_ylabel("evaluation return")
    ax.set_title(exp.title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    if with_usage:
        usage = axes[1]
        for label in labels:
            c = curves(rows, label, key="options/rl_fraction")
            usage.plot(c["env_steps"], c["mean"], color="tab:blue", label="RL option")
            usage.plot(c["env_steps"], 1 - c["mean"], color="tab:red", label="hard-coded option")
        usage.set_xlabel("environment steps")
        usage.set_ylabel("fraction of greedy steps (evaluation)")
        usage.set_title("Fig. 6: option usage over time", fontsize=9)
        usage.legend(fontsize=7)
        usage.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png_path, dpi=120)
    plt.close(fig)
