"""Where the tree's time goes: each leaf of the real tree lands in the right activity and
sub-tree, and against a real world server every tick is charged to a real leaf."""

from __future__ import annotations

import pytest
from py_trees.behaviour import Behaviour

from minecraft.agent.diamond_tree import build_tree, run_episode
from minecraft.agent.leaves.percept import Percept
from minecraft.agent.tree_profile import (
    MISSION_START,
    START_KEY,
    LeafTimes,
    TimeProfile,
    aggregate,
    classify,
)
from minecraft.malmo.client import MalmoClient
from tests.minecraft.agent.test_diamond_integration import _pool
from tests.minecraft.conftest import flat_mission


def _find(root: Behaviour, leaf: str, under: str) -> Behaviour:
    """The first leaf named ``leaf`` with ancestors named as in ``under`` ("A/B")."""
    for b in root.iterate():
        if b.name != leaf:
            continue
        ancestors = set()
        node = b.parent
        while node is not None:
            ancestors.add(node.name)
            node = node.parent
        if set(under.split("/")) <= ancestors:
            return b
    raise AssertionError(f"no {leaf!r} under {under!r}")


@pytest.mark.parametrize(
    ("leaf", "under", "subtree", "activity"),
    [
        ("Step to cell", "Wood/Mine log", "Wood", "travel"),
        ("Break block", "Wood/Mine log", "Wood", "travel"),
        ("Mine target", "Wood/Mine log", "Wood", "digging"),
        ("Step to cell", "Wood/Find log", "Wood", "travel"),
        ("Ascend", "Ensure iron_pickaxe/Go up for wood", "Ensure log", "searching"),
        ("Break block", "Ensure iron_pickaxe/Go up for wood", "Ensure log", "searching"),
        ("Step to cell", "Re-plan (wood)/Mine log", "Ensure log", "recovering"),
        ("Step to cell", "Re-plan (elsewhere)/Move away", "Re-plan (elsewhere)", "recovering"),
        ("Re-plan: wood?", "Re-plan", "Re-plan (wood)", "waiting"),
        ("Explore (surface)", "Wood", "Wood", "searching"),
        ("Mine target", "Mine iron_ore", "Ensure iron_ore", "digging"),
        ("Step to cell", "Ensure iron_ore/Go down to y=12", "Ensure iron_ore", "descending"),
        ("Break block", "Diamond/Go down to y=12", "Diamond", "descending"),
        ("Step to cell", "Diamond/Explore", "Diamond", "searching"),
        ("Craft furnace", "Ensure furnace", "Ensure furnace", "crafting"),
        ("Craft planks", "Ensure crafting_table", "Ensure planks x4", "crafting"),
        ("Step to cell", "Pick up drops", "Pick up drops", "travel"),
        ("Eat", "Survive", "Survive", "survival"),
        ("Drop nearby?", "Pick up drops", "Pick up drops", "waiting"),
    ],
)
def test_classify_places_real_leaves(leaf: str, under: str, subtree: str, activity: str) -> None:
    root, _ = build_tree(seed=0)
    key = classify(_find(root, leaf, under))
    assert (key.leaf, key.subtree, key.activity) == (leaf, subtree, activity)


def _p(tick: int, **inventory: int) -> Percept:
    return Percept(x=0.5, y=4.0, z=0.5, tick=tick, inventory=dict(inventory))


def test_profile_charges_ticks_to_the_leaf_that_acted() -> None:
    root, ctx = build_tree(seed=0)
    walk = _find(root, "Step to cell", "Wood/Mine log")
    dig = _find(root, "Mine target", "Wood/Mine log")
    prof = TimeProfile()
    prof.observed(_p(3))  # 3 ticks of loading before the tree acts
    prof.acted(walk, ctx)
    prof.observed(_p(10))  # 7 ticks walking
    prof.acted(dig, ctx)
    prof.observed(_p(30))  # 20 ticks digging
    prof.acted(walk, ctx)  # back to walking, nothing gained: idle re-entry
    prof.observed(_p(35, log=1))
    prof.acted(dig, ctx)  # a log since digging last ran: progress
    prof.finish(41)
    t = prof.summary()
    assert t.total == 41
    assert t.ticks[START_KEY] == 3
    assert t.by("activity") == {"waiting": 3, "travel": 12, "digging": 26}
    assert t.by("leaf") == {MISSION_START: 3, "Step to cell": 12, "Mine target": 26}
    walk_key, dig_key = classify(walk), classify(dig)
    assert t.entries == {walk_key: 2, dig_key: 2}
    assert t.idle_entries == {walk_key: 1}
    assert t.last == dig_key


def test_profile_measures_the_longest_wait_and_counts_firings() -> None:
    """Consecutive waiting ticks add up across waiting leaves and restart when an
    action leaf runs; each watchdog firing is charged to the leaf running then."""
    root, ctx = build_tree(seed=0)
    walk = _find(root, "Step to cell", "Wood/Mine log")
    has_log = _find(root, "Has 1 log?", "Ensure iron_pickaxe")
    drop = _find(root, "Drop nearby?", "Pick up drops")
    prof = TimeProfile()
    prof.acted(has_log, ctx)
    prof.observed(_p(30))  # 30 waiting (with the loading tick 0)
    prof.acted(walk, ctx)
    prof.observed(_p(40))
    prof.acted(has_log, ctx)
    prof.observed(_p(70))
    prof.fired()
    prof.acted(drop, ctx)  # another waiting leaf: the same stretch goes on
    prof.observed(_p(100))
    prof.acted(walk, ctx)
    prof.finish(110)
    t = prof.summary()
    assert t.longest_wait == 60
    assert t.longest_wait_leaf == classify(has_log)
    assert t.watchdog == {classify(has_log): 1}


def test_aggregate_shares_and_per_world_figures() -> None:
    a, b = classify(None), START_KEY
    worlds = [LeafTimes(ticks={a: 30, b: 10}), LeafTimes(ticks={b: 60})]
    rows = {r.name: r for r in aggregate(worlds, "leaf")}
    none_row = rows["(none) [(none): waiting]"]
    assert none_row.share == pytest.approx(0.3)
    assert (none_row.mean, none_row.median, none_row.worlds) == (15.0, 15.0, 1)
    assert rows[f"{MISSION_START} [{MISSION_START}: waiting]"].share == pytest.approx(0.7)


@pytest.mark.service  # a real world server process
def test_every_tick_of_a_real_episode_goes_to_a_real_leaf() -> None:
    # A trunk 4 blocks east: walk, chop, pick up, craft planks.
    deco = '<DrawCuboid x1="4" y1="4" z1="0" x2="4" y2="6" z2="0" type="log"/>'
    pool = _pool()
    try:
        client = MalmoClient("127.0.0.1", pool.ports[0], synchronous=True, timeout=10)
        client.init(flat_mission(decorators=deco, grid_radius=7, ms_per_tick=50))
        prof = TimeProfile()
        result = run_episode(
            client,
            seed=3,
            goal="planks",
            max_ticks=600,
            stop_when=lambda p: p.count("planks") >= 4,
            profile=prof,
        )
        client.close()
    finally:
        pool.stop()
    t = prof.summary()
    assert result.end == "stopped", result
    assert t.total == result.ticks > 0
    leaves = [b for b in build_tree(seed=3, goal="planks")[0].iterate() if not b.children]
    names = {b.name for b in leaves}
    assert set(t.by("leaf")) - {MISSION_START} <= names
    by = t.by("activity")
    assert by.get("travel", 0) > 0 and by.get("digging", 0) > 0 and by.get("crafting", 0) > 0


@pytest.mark.service  # a real world server process
def test_gif_records_frames_with_the_running_leaf(tmp_path) -> None:
    from PIL import Image

    from minecraft.agent.tree_gif import record_gif

    deco = '<DrawCuboid x1="4" y1="4" z1="0" x2="4" y2="6" z2="0" type="log"/>'
    pool = _pool()
    try:
        path = tmp_path / "tree.gif"
        mission = flat_mission(decorators=deco, grid_radius=7, ms_per_tick=50, video=True)
        result, n = record_gif(pool.ports[0], mission, path, seed=3, max_ticks=60, every=10)
    finally:
        pool.stop()
    assert n >= 5 and result.ticks > 0
    with Image.open(path) as im:
        assert 2 <= im.n_frames <= n  # Pillow merges identical neighbouring frames
        assert im.size == (16 * 3, 12 * 3 + 28)


@pytest.mark.service  # a real world server process
def test_gif_with_corrections_captions_what_they_did(tmp_path) -> None:
    import numpy as np
    from PIL import Image

    from minecraft.agent.corrections import Corrections
    from minecraft.agent.tree_gif import record_gif

    calls: list[np.ndarray] = []

    def slower(obs: np.ndarray) -> np.ndarray:  # μ(s) at 0.9 of its speed
        calls.append(obs)
        mu = obs[-4:]
        return np.array([0.9 * mu[0], 0.9 * mu[1], mu[2], mu[3]])

    deco = '<DrawCuboid x1="4" y1="4" z1="0" x2="4" y2="6" z2="0" type="log"/>'
    pool = _pool()
    try:
        path = tmp_path / "tree.gif"
        mission = flat_mission(decorators=deco, grid_radius=7, ms_per_tick=50, video=True)
        result, n = record_gif(
            pool.ports[0], mission, path, seed=3, max_ticks=60, every=10,
            corrections=Corrections(travel=slower),
        )  # fmt: skip
    finally:
        pool.stop()
    assert n >= 5 and result.ticks > 0 and calls  # the walk to the log was corrected
    with Image.open(path) as im:
        assert im.size == (16 * 3, 12 * 3 + 41)  # a third caption line: the correction
