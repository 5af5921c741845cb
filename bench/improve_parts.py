"""What each acting-side part of the default recipe earns, on a trained run, for free.

Value-based switching and the final selection change only how the trained networks act,
not how they learn, so one run scores all of them on the same held-out episodes:

    selected   the run's final policy as `graft eval` scores it (switching, then selection)
    switching  the same networks with switching, the selection undone
    policy     the same networks acting π (or argmax Q) everywhere: neither part
    alone      with `selection.best_in_run`: what the selection would have kept from the
               final policy alone, tested at its uncorrected z (the final policy or the tree)

(`bench/improve.py --parts`; the learning-side parts — the penalty, the burn-in, the decayed
margin loss — need runs of their own: `--set` them off.)

`reselect` applies the current final-selection rule to a finished run, on the episodes
`graft train` selects on now (`bench/improve.py --reselect`, for runs trained under an older
rule or on the older evaluation episodes).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

import graft
from bench.seeds import evaluate_run
from learner.selection import SelectionConfig

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
    from graft.trained import load_behaviour

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
    alone = final_alone(run_dir, behaviour, scores, config=config, episodes=episodes, seed=seed)
    scores |= {ALONE: alone} if alone is not None else {}
    saved[key] = scores
    cache.write_text(json.dumps(saved))
    return scores


ALONE = "alone"


def final_alone(
    run_dir: Path, behaviour: Any, scores: dict[str, float], *, config: Any, episodes: int,
    seed: int,
) -> Optional[float]:  # fmt: skip
    """For a run whose selection had its best in-run policy as a candidate: the score of
    what the selection would have kept from the final policy alone (the summary's
    ``policy_alone_kept``): the final networks with switching (saved in RUN/unselected when
    the earlier policy was kept), or the tree. None for other runs."""
    from graft.trained import load_behaviour
    from learner.loop import UNSELECTED

    record = json.loads((run_dir / "summary.json").read_text()).get("selection") or {}
    if "best" not in record:
        return None
    if record["policy_alone_kept"]:
        unselected = sorted((run_dir / UNSELECTED).glob("ckpt-*.pt"))
        if not unselected:  # the final networks are the run's own
            return scores["switching"]
        behaviour, _ = load_behaviour(unselected[-1])
    else:
        behaviour.tree_only = True
    played = graft.evaluate(behaviour.greedy, env=config.env_spec(), episodes=episodes, seed=seed)
    return played.mean


def reselect(
    run_dir: Path, *, rule: SelectionConfig, episodes: int, eval_seed: int
) -> dict[str, float]:
    """Applies the final selection `rule` (`learner.selection.tree_wins`) to a finished run,
    on the episodes a run with its seed selects on now (`graft.seeds.evaluation_seed`), and
    writes the choice into its last checkpoint and its summary (``reselected``: by what
    rule, when the record changed). When the choice changed (the tree kept or not) it
    scores the final policy again as `bench.seeds.run_seed` does (`graft eval`, `episodes`
    from `eval_seed`) into ``eval.json``.

    Returns:
        The selection record, as `graft train` writes it (``policy``, ``tree``, ``tree_kept``).
    """
    import torch

    from actors.evaluator import play_episodes
    from graft.seeds import evaluation_seed
    from graft.trained import load_behaviour
    from learner.checkpoint import find_checkpoint, load_checkpoint
    from learner.selection import tree_wins

    behaviour, config = load_behaviour(run_dir)
    seed = evaluation_seed(config.seed)
    returns = {}
    for name, tree_only in (("policy", False), ("tree", True)):
        behaviour.tree_only = tree_only
        played = play_episodes(
            behaviour.greedy, env=config.env_spec(), episodes=rule.episodes, seed=seed
        )
        returns[name] = [float(r) for r in played.returns]
    kept = tree_wins(returns["policy"], returns["tree"], z=rule.z)
    checkpoint, _ = find_checkpoint(run_dir)
    state = load_checkpoint(checkpoint)
    state["algorithm"]["tree_only"] = kept
    torch.save(state, checkpoint)
    record = {k: float(np.mean(v)) for k, v in returns.items()} | {"tree_kept": float(kept)}
    summary = json.loads((run_dir / "summary.json").read_text())
    before = summary.get("selection") or {}
    if not all(math.isclose(before.get(k, math.nan), v, rel_tol=1e-9) for k, v in record.items()):
        rule_used = {"episodes": rule.episodes, "z": rule.z, "seed": seed}
        summary |= {"selection": record, "reselected": rule_used}
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    if before.get("tree_kept") != record["tree_kept"]:
        done = run_dir / "eval.json"
        wall_s = json.loads(done.read_text()).get("wall_s", 0.0) if done.exists() else 0.0
        evaluate_run(run_dir, episodes=episodes, eval_seed=eval_seed, wall_s=wall_s)
    return record


def parts_table(rows: dict[str, list[tuple[int, float, float, dict[str, float]]]]) -> str:
    """Markdown: per task and seed, the tree, each variant and the final, minus the tree."""
    alone = any(ALONE in scores for seeds in rows.values() for *_, scores in seeds)
    shown = [*reversed(PARTS), *([ALONE] if alone else [])]
    lines = [
        "| task | seed | tree | π everywhere | with switching |"
        + (" final policy alone, selected |" if alone else "")
        + " selected (final) |",
        "|---|---|---|---|---|" + ("---|" if alone else "") + "---|",
    ]
    for task, seeds in rows.items():
        for seed, tree, final, scores in seeds:
            cells = [
                f"{scores[p]:.1f} ({scores[p] - tree:+.1f})" if p in scores else "–" for p in shown
            ]
            lines.append(
                f"| {task} | {seed} | {tree:.1f} | {' | '.join(cells)} "
                f"| {final:.1f} ({final - tree:+.1f}) |"
            )
    return "\n".join(lines)
