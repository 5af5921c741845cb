"""What `graft tune` shows: the table of points, CSV, PNG, and the recommended configuration."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from graft.tuning.grid import COST_KNOBS, knob_key
from graft.tuning.measure import SATURATED, SKIPPED_LIMIT

OBJECTIVES = {
    "inserted": "inserted_per_s",
    "updates": "learner_updates_per_s",
}
"""What the recommendation maximises: env steps inserted per s, or learner updates per s."""

COLUMNS = (
    ("env_steps_per_s", "steps/s", "{:.0f}"),
    ("inserted_per_s", "inserted/s", "{:.0f}"),
    ("actor_insert_wait", "actor insert wait", "{:.0%}"),
    ("insert_limiter_s_per_s", "of it limiter", "{:.0%}"),
    ("insert_network_s_per_s", "network", "{:.0%}"),
    ("learner_updates_per_s", "updates/s", "{:.1f}"),
    ("learner_wait", "learner wait", "{:.0%}"),
    ("publish_ms", "publish ms", "{:.1f}"),
    ("policy_lag", "policy lag", "{:.2f}"),
    ("skipped", "skipped", "{:.1%}"),
    ("cpu_learner", "CPU learner", "{:.2f}"),
    ("cpu_actors", "CPU actors", "{:.2f}"),
    ("cpu_replay", "CPU replay", "{:.2f}"),
    ("cpu_machine", "CPU machine", "{:.2f}"),
    ("bottleneck", "bottleneck", "{}"),
)
"""Printed columns: (row key, header, format). CPU is in cores over the measured time."""

SHARD_COLUMNS = (
    ("shard_inserted_per_s", "inserted/s per shard", "{}"),
    ("shard_cpu_replay", "CPU replay per shard", "{}"),
)
"""Printed after "CPU replay" when a point ran more than one replay shard."""


def _columns(rows: Sequence[dict[str, Any]]) -> list[tuple[str, str, str]]:
    columns = list(COLUMNS)
    if any("/" in str(r.get("shard_inserted_per_s", "")) for r in rows):
        at = [key for key, _, _ in columns].index("cpu_replay") + 1
        columns[at:at] = SHARD_COLUMNS
    return columns


RULE = (
    f"bottleneck rule: the learner publishing >= {SATURATED:.0%} of the time -> broadcast; "
    f"real-time actors skipping > {SKIPPED_LIMIT:.0%} of ticks -> actors; else, with 'waits' "
    f"meaning >= {SATURATED:.0%} of the measured time: actors wait on inserts and the learner "
    "does not -> learner; the learner waits for batches and the actors do not -> actors; "
    "both wait -> replay (rate limiter or server); neither -> none"
)


def table(rows: Sequence[dict[str, Any]], knobs: Sequence[str]) -> str:
    """The points as a Markdown table (with per-shard columns when a point had shards)."""
    columns = _columns(rows)
    head = [*knobs, *(h for _, h, _ in columns)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row[k]) for k in knobs] + [
            "-" if row[key] != row[key] else fmt.format(row[key])  # nan: not measured
            for key, _, fmt in columns
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_csv(rows: Sequence[dict[str, Any]], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def recommend(rows: Sequence[dict[str, Any]], objective: str) -> dict[str, Any]:
    """The point with the highest objective (ties: the first, i.e. the cheaper grid value)."""
    key = OBJECTIVES[objective]
    return max(rows, key=lambda r: r[key])


def preset_lines(best: dict[str, Any], knobs: Sequence[str], algorithm: str) -> list[str]:
    """YAML lines setting the recommended knobs (section fields nested); the knobs that
    are not preset fields as comments."""
    flat: dict[str, Any] = {}
    comments = []
    for name in knobs:
        key = knob_key(name, algorithm)
        if key == "samples_per_insert":
            batch = best.get("batch_size", best.get(knob_key("batch_size", algorithm)))
            note = (
                f" (updates_per_env_step = {best[name]} / batch size{f' {batch}' if batch else ''})"
            )
            if batch:
                flat["updates_per_env_step"] = round(float(best[name]) / float(batch), 6)
            else:
                comments.append(f"# samples per insert {best[name]}{note}")
        elif key in COST_KNOBS:
            comments.append(f"# {key}: {best[name]} (a property of the simulated parts)")
        else:
            flat[key] = best[name]
    lines: list[str] = []
    sections: dict[str, list[str]] = {}
    for key, value in flat.items():
        section, _, field = key.partition(".")
        if field:
            sections.setdefault(section, []).append(f"  {field}: {value}")
        else:
            lines.append(f"{key}: {value}")
    for section, fields in sections.items():
        lines += [f"{section}:", *fields]
    return lines + comments


def plot(rows: Sequence[dict[str, Any]], knobs: Sequence[str], path: Path, title: str) -> None:
    """One bar per point in four panels: inserted env steps/s, learner updates/s, the
    learner's and actors' waits, CPU per component; bars coloured by bottleneck."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {
        "learner": "tab:blue",
        "actors": "tab:orange",
        "replay": "tab:red",
        "broadcast": "tab:purple",
        "none": "tab:gray",
    }
    labels = ["\n".join(f"{k}={r[k]}" for k in knobs) for r in rows]
    x = range(len(rows))
    bar_colours = [colours[r["bottleneck"]] for r in rows]
    fig, axes = plt.subplots(4, 1, figsize=(max(6, 0.9 * len(rows) + 2), 11), sharex=True)
    axes[0].bar(x, [r["inserted_per_s"] for r in rows], color=bar_colours)
    axes[0].set_ylabel("env steps inserted/s")
    axes[1].bar(x, [r["learner_updates_per_s"] for r in rows], color=bar_colours)
    axes[1].set_ylabel("learner updates/s")
    width = 0.4
    axes[2].bar([i - width / 2 for i in x], [r["learner_wait"] for r in rows], width,
                label="learner waits for batches", color="tab:blue")  # fmt: skip
    axes[2].bar([i + width / 2 for i in x], [r["actor_insert_wait"] for r in rows], width,
                label="actors wait on inserts", color="tab:orange")  # fmt: skip
    axes[2].axhline(SATURATED, color="k", linestyle="--", linewidth=0.8)
    axes[2].set_ylabel("share of time")
    axes[2].legend(fontsize=8)
    bottom = [0.0] * len(rows)
    for key, name in (("cpu_learner", "learner"), ("cpu_actors", "actors"),
                      ("cpu_replay", "replay server")):  # fmt: skip
        values = [r[key] for r in rows]
        axes[3].bar(x, values, bottom=bottom, label=name)
        bottom = [b + v for b, v in zip(bottom, values, strict=True)]
    axes[3].plot(x, [r["cpu_machine"] for r in rows], "k.", label="whole machine")
    axes[3].set_ylabel("CPU (cores)")
    axes[3].legend(fontsize=8)
    axes[3].set_xticks(list(x))
    axes[3].set_xticklabels(labels, fontsize=8)
    handles = [matplotlib.patches.Patch(color=c, label=b) for b, c in colours.items()]
    fig.suptitle(title, y=0.995)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.legend(handles=handles, title="bottleneck", fontsize=8, ncol=5, loc="upper center",
               bbox_to_anchor=(0.5, 0.97))  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
