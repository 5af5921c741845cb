"""The tree alone against the tree with learned corrections, world by world (for
bench/diamond.py): success, deaths, median and mean time to diamond, the paired sign
test, and the time per activity and per leaf side by side."""

from __future__ import annotations

import math
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from minecraft.agent.diamond_tree import EpisodeResult  # noqa: E402
from minecraft.agent.tree_profile import ACTIVITIES, LeafTimes  # noqa: E402

Row = tuple[EpisodeResult, float, LeafTimes]


def sign_test(wins: int, losses: int) -> float:
    """Two-sided sign test: the chance of a split at least this uneven if each (non-tied)
    world were a coin flip."""
    n, k = wins + losses, min(wins, losses)
    return min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2**n) if n else 1.0


def time_to_diamond(r: EpisodeResult, limit: int) -> int:
    """Ticks to the diamond; a world without one counts as the time limit."""
    return r.ticks if r.diamond else max(limit, r.ticks)


def _s(ticks: float) -> str:
    return f"{ticks / 20:.1f}"


def summary_row(name: str, rows: list[Row], limit: int) -> str:
    got = [r.ticks for r, _, _ in rows if r.diamond]
    capped = [time_to_diamond(r, limit) for r, _, _ in rows]
    median = _s(statistics.median(got)) if got else "-"
    mean = _s(statistics.fmean(got)) if got else "-"
    return (
        f"| {name} | {len(got)}/{len(rows)} | {sum(r.deaths for r, _, _ in rows)} | {median} | "
        f"{mean} | {_s(statistics.median(capped))} | {_s(statistics.fmean(capped))} |"
    )


def comparison(tree: list[Row], corrected: list[Row], *, limit: int) -> str:
    """Markdown: the two agents on the same worlds (rows paired by seed)."""
    assert [r.seed for r, _, _ in tree] == [r.seed for r, _, _ in corrected]
    lines = [
        "| agent | diamonds | deaths | median s to diamond | mean s to diamond | "
        "median s (no diamond = limit) | mean s (no diamond = limit) |",
        "|---|---|---|---|---|---|---|",
        summary_row("tree alone", tree, limit),
        summary_row("tree + corrections", corrected, limit),
    ]
    pairs = [
        (time_to_diamond(c, limit), time_to_diamond(t, limit))
        for (t, _, _), (c, _, _) in zip(tree, corrected, strict=True)
    ]
    faster = sum(c < t for c, t in pairs)
    slower = sum(c > t for c, t in pairs)
    ratios = [c / t for c, t in pairs]
    lines += [
        "",
        f"paired on {len(pairs)} worlds: the corrected tree is faster on {faster}, slower on "
        f"{slower}, tied on {len(pairs) - faster - slower} (sign test p = "
        f"{sign_test(faster, slower):.3g}); median time ratio {statistics.median(ratios):.3f}"
        f" (mean {statistics.fmean(ratios):.3f})",
        "",
        "| activity | tree alone: mean s per world | tree + corrections: mean s per world "
        "| change |",
        "|---|---|---|---|",
    ]
    for a in ACTIVITIES:
        t = statistics.fmean(p.by("activity").get(a, 0) for _, _, p in tree)
        c = statistics.fmean(p.by("activity").get(a, 0) for _, _, p in corrected)
        change = f"{100 * (c - t) / t:+.0f} %" if t else "-"
        lines.append(f"| {a} | {_s(t)} | {_s(c)} | {change} |")
    lines += ["", "| leaf [sub-tree: activity] | tree alone: mean s per world | "
              "tree + corrections: mean s per world |", "|---|---|---|"]  # fmt: skip
    keys = {k for _, _, p in tree + corrected for k in p.ticks}
    per = {
        k: (
            statistics.fmean(p.ticks.get(k, 0) for _, _, p in tree),
            statistics.fmean(p.ticks.get(k, 0) for _, _, p in corrected),
        )
        for k in keys
    }
    for k, (t, c) in sorted(per.items(), key=lambda kv: -max(kv[1]))[:15]:
        lines.append(f"| {k.leaf} [{k.subtree}: {k.activity}] | {_s(t)} | {_s(c)} |")
    return "\n".join(lines)
