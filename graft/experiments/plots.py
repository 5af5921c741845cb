"""Drawing an experiment's results: across-seed curves per variant and the figure's PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from graft.experiments.figures import HARD_CODED_LEVEL, Figure


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


def plot_figure(rows: list[dict[str, str]], png_path: Path, figure: Figure) -> None:
    """Mean ± std across seeds per variant, with the hard-coded policy's level as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [v.label for v in figure.variants if any(r["variant"] == v.label for r in rows)]
    with_usage = any(r.get("options/rl_fraction") for r in rows)
    fig, axes = plt.subplots(1, 2 if with_usage else 1, figsize=(11 if with_usage else 7, 4.5))
    ax = axes[0] if with_usage else axes
    for i, label in enumerate(labels):
        c = curves(rows, label)
        if figure.final_only:
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
    if figure.final_only:
        ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("evaluation return (100 episodes)")
    else:
        ax.set_xlabel("environment steps")
        ax.set_ylabel("evaluation return")
    ax.set_title(figure.title, fontsize=9)
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
