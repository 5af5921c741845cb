"""Running the paper's figures: every variant × seed a `train` run, in parallel on Ray.

    graft experiment fig4 --seeds 10
      └─ one Ray task per (variant, seed): a whole `train` run (its own replay server,
         actors, evaluator and learner), at most --parallel at a time
      └─ runs/experiments/fig4/{results.csv, fig4.png, <variant>-s<seed>/}

The figures themselves are data in `figures`; `plots` draws them.
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray

from graft.experiments.figures import FIGURES, Variant
from graft.experiments.plots import curves, plot_figure
from graft.experiments.stats import MIN_SEEDS, summarize
from graft.validation import ConfigError


@ray.remote(num_cpus=0.25)
def _run_one(preset: str, overrides: dict[str, Any], run_dir: str, address: str) -> dict[str, Any]:
    """One seed of one variant: a full `train` run inside a Ray task."""
    import torch

    from graft.config import load_preset
    from graft.orchestration.launcher import train

    torch.set_num_threads(1)
    result = train(
        load_preset(preset, **overrides), run_dir=Path(run_dir), progress=False, address=address
    )
    return {"summary": result.summary, "evaluations": result.evaluations}


@dataclass(frozen=True)
class Job:
    """One seed of one variant: its preset, the merged overrides and its run folder."""

    variant: Variant
    seed: int
    overrides: dict[str, Any]
    run_dir: Path


def plan_experiment(
    name: str,
    *,
    seeds: int,
    out_dir: Path,
    parallel: int = 2,
    overrides: Optional[dict[str, Any]] = None,
    address: str = "local",
    only: Optional[list[str]] = None,
) -> list[Job]:
    """Every variant × seed of an experiment, each config checked; writes and starts nothing.

    Raises:
        ConfigError: unknown experiment or variant, a variant's preset refusing the
            overrides (naming the variant), a run folder that already exists, or more runs
            in parallel than a local Ray instance can place.
    """
    from graft.config import load_preset
    from graft.orchestration.preflight import ray_cpus, run_cpus
    from graft.placement import local_cpus

    if name not in FIGURES:
        raise ConfigError(f"unknown experiment {name!r}; choose from {sorted(FIGURES)}")
    if seeds < 1 or parallel < 1:
        raise ConfigError(f"seeds={seeds} and parallel={parallel} must be >= 1")
    figure = FIGURES[name]
    labels = [v.label for v in figure.variants]
    unknown = sorted(set(only or []) - set(labels))
    if unknown:
        raise ConfigError(f"{name} has no variant(s) {unknown}; its variants: {labels}")
    chosen = [v for v in figure.variants if not only or v.label in only]
    jobs, widest = [], (0.0, "")
    # Seed-major: an experiment cut short still has every variant on the same seeds.
    for seed in range(seeds):
        for variant in chosen:
            merged = {**figure.shared, **variant.overrides, **(overrides or {}), "seed": seed}
            try:
                config = load_preset(variant.preset, **merged)
            except ValueError as e:
                raise ConfigError(
                    f"variant {variant.label!r} (preset {variant.preset}): {e}"
                ) from None
            run_dir = out_dir / name / f"{_slug(variant)}-s{seed}"
            if run_dir.exists() and any(run_dir.iterdir()):
                raise ConfigError(
                    f"variant {variant.label!r}: run folder {run_dir} already exists; remove "
                    "it to run the variant again, or give another --out"
                )
            jobs.append(Job(variant, seed, merged, run_dir))
            widest = max(widest, (ray_cpus(_run_one) + run_cpus(config), variant.label))
    need, have = widest[0] * min(parallel, len(jobs)), local_cpus()
    if address == "local" and need > have:
        raise ConfigError(
            f"parallel={parallel} does not fit the local Ray instance: a run of variant "
            f"{widest[1]!r} takes {widest[0]:g} CPUs (its task, actors and evaluator), "
            f"{min(parallel, len(jobs))} at a time {need:g}, it has {have:g}; at most "
            f"{max(int(have // widest[0]), 1)} at a time"
        )
    return jobs


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
        ConfigError: see `plan_experiment`; nothing has run then.
    """
    jobs = plan_experiment(
        name,
        seeds=seeds,
        out_dir=out_dir,
        parallel=parallel,
        overrides=overrides,
        address=address,
        only=only,
    )
    folder = out_dir / name
    folder.mkdir(parents=True, exist_ok=True)
    csv_path = folder / "results.csv"
    chosen = {job.variant.label for job in jobs}
    kept = [
        r for r in (read_rows(csv_path) if csv_path.exists() else []) if r["variant"] not in chosen
    ]
    rows: list[dict[str, Any]] = list(kept)
    pending: dict[Any, tuple[Variant, int]] = {}
    queue, start = list(jobs), time.perf_counter()
    while queue or pending:
        while queue and len(pending) < parallel:
            job = queue.pop(0)
            ref = _run_one.remote(job.variant.preset, job.overrides, str(job.run_dir), address)
            pending[ref] = (job.variant, job.seed)
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
    from service.metrics import read_evaluations

    rows: list[dict[str, Any]] = []
    for variant in FIGURES[name].variants:
        for run in sorted(folder.glob(f"{_slug(variant)}-s*")):
            if not (run / "summary.json").exists():
                continue  # unfinished
            for step, mean, std in read_evaluations(run / "metrics.csv"):
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
    figure, folder = FIGURES[name], out_dir / name
    csv_path, png_path = folder / "results.csv", folder / f"{name}.png"
    if not csv_path.exists():
        write_rows(csv_path, rows_from_runs(name, folder))
    rows = read_rows(csv_path)
    plot_figure(rows, png_path, figure)
    summary = summarise(rows, [v.label for v in figure.variants])
    write_rows(folder / "summary.csv", summary)
    for row in summary:
        print(", ".join(f"{k}={v}" for k, v in row.items()))
    return csv_path, png_path


def summarise(
    rows: list[dict[str, str]], labels: list[str], *, threshold: float = -200.0, at: int = 5000
) -> list[dict[str, Any]]:
    """Per variant: seeds, final return (mean ± std over seeds; from 3 seeds on also its
    95 % bootstrap interval and the IQM, graft/experiments/stats.py), the first env-step count
    at which the across-seed mean reaches `threshold`, and the across-seed std at the
    evaluation nearest `at` env steps."""
    out = []
    for label in labels:
        c = curves(rows, label)
        if not c["seeds"]:
            continue
        finals = c["per_seed"][:, -1]
        stats = summarize(finals)
        interval = stats.n >= MIN_SEEDS
        reached = np.flatnonzero(c["mean"] >= threshold)
        near = int(np.argmin(np.abs(c["env_steps"] - at)))
        out.append(
            {
                "variant": label,
                "seeds": c["seeds"],
                "final_env_steps": int(c["env_steps"][-1]),
                "final_mean": round(float(finals.mean()), 1),
                "final_std": round(float(finals.std()), 1),
                "final_ci95_low": round(stats.mean_ci[0], 1) if interval else None,
                "final_ci95_high": round(stats.mean_ci[1], 1) if interval else None,
                "final_iqm": round(stats.iqm, 1) if interval else None,
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
