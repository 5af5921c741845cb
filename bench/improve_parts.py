"""What each acting-side part of the default recipe earns, on a trained run, for free.

Value-based switching and the final selection change only how the trained networks act,
not how they learn, so one run scores all of them on the same held-out episodes:

    selected   the run's final policy as `graft eval` scores it (switching, then selection)
    switching  the same networks with switching, the selection undone
    policy     the same networks acting π (or argmax Q) everywhere: neither part

(`bench/improve.py --parts`; the learning-side parts — the penalty, the burn-in, the decayed
margin loss — need runs of their own: `--set` them off.)
"""

from __future__ import annotations

import json
from pathlib import Path

import graft

PARTS = ("switching", "policy")
"""The variants scored besides the final policy, in the order the table prints them."""


def part_scores(run_dir: Path, *, episodes: int, seed: int) -> dict[str, float]:
    """Mean returns of each variant of `run_dir`'s final networks on `episodes` episodes
    reset from `seed` (cached in RUN/parts.json)."""
    cache = run_dir / "parts.json"
    key = f"{episodes}@{seed}"
    saved = json.loads(cache.read_text()) if cache.exists() else {}
    if key in saved:
        return dict(saved[key])
    from service.run.trained import load_behaviour

    behaviour, config = load_behaviour(run_dir)
    scores: dict[str, float] = {}
    for part in PARTS:
        behaviour.tree_only = False  # the selection undone
        if part == "policy":  # switching off too: the backbone's critic, DQN's margin
            if hasattr(behaviour, "critic"):
                behaviour.critic = None
            behaviour.switch_margin = None
        played = graft.evaluate(
            behaviour.greedy, env=config.env_spec(), episodes=episodes, seed=seed
        )
        scores[part] = played.mean
    saved[key] = scores
    cache.write_text(json.dumps(saved))
    return scores


def parts_table(rows: dict[str, list[tuple[int, float, float, dict[str, float]]]]) -> str:
    """Markdown: per task and seed, the tree, each variant and the final, minus the tree."""
    lines = [
        "| task | seed | tree | π everywhere | with switching | selected (final) |",
        "|---|---|---|---|---|---|",
    ]
    for task, seeds in rows.items():
        for seed, tree, final, scores in seeds:
            cells = [f"{scores[p]:.1f} ({scores[p] - tree:+.1f})" for p in reversed(PARTS)]
            lines.append(
                f"| {task} | {seed} | {tree:.1f} | {' | '.join(cells)} "
                f"| {final:.1f} ({final - tree:+.1f}) |"
            )
    return "\n".join(lines)
