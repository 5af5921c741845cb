"""The learned corrections inside the diamond tree: the drops decision's observation and
candidates, the travel correction acting at "Step to cell" only, and the tree's
"Drop nearby?" leaving what a correction chose to leave."""

from __future__ import annotations

import numpy as np
import py_trees
import pytest

from minecraft.agent.corrections import (
    DROP_OBS_DIM,
    SKIPPED_KEY,
    TravelCorrection,
    drop_observation,
    new_drops,
)
from minecraft.agent.leaves.context import Context, share
from minecraft.agent.leaves.goals import ChooseDrop
from minecraft.agent.leaves.percept import ItemSeen, Percept
from minecraft.agent.leaves.travel import AtDestination, StepTo
from minecraft.agent.travel_control import OBS_DIM


def _item(name: str, dx: float, dy: float, dz: float, uid: str) -> ItemSeen:
    return ItemSeen(name, 10.5 + dx, 20.0 + dy, 30.5 + dz, 1, uid)


def _percept(*items: ItemSeen, **inventory: int) -> Percept:
    return Percept(10.5, 20.0, 30.5, items=list(items), inventory=dict(inventory))


def test_drop_observation_by_hand() -> None:
    p = _percept(cobblestone=24, stone_pickaxe=1, wooden_pickaxe=1)
    obs = drop_observation(p, _item("cobblestone", 2.0, -1.0, 0.0, "a"))
    expected = np.zeros(DROP_OBS_DIM, np.float32)
    expected[1] = 1.0  # cobblestone, second of DROP_ITEMS
    expected[8] = 24 / 16
    expected[9:13] = (0.5, -0.25, 0.0, 0.75)
    expected[13:17] = (1.0, 1.0, 0.0, 0.0)  # wooden, stone pickaxe; no furnace, iron pickaxe
    np.testing.assert_allclose(obs, expected)
    held = drop_observation(_percept(log=200), _item("log", 0, 0, 0, "b"))
    assert held[8] == 4.0  # the count is capped


def test_new_drops_are_wanted_in_reach_undecided_nearest_first() -> None:
    p = _percept(
        _item("iron_ore", 3.0, 0.0, 0.5, "far"),  # 3.5 blocks
        _item("dirt", 0.5, 0.0, 0.0, "unwanted"),
        _item("log", 1.0, 0.0, 0.0, "near"),
        _item("coal", 4.0, 1.0, 0.0, "out of reach"),
        _item("diamond", 0.2, 0.0, 0.0, "decided"),
    )
    assert [it.uid for it in new_drops(p, {"decided"})] == ["near", "far"]


def _leaf_ctx(leaf_type: type, **kwargs: object) -> tuple[object, Context]:
    ctx = Context()
    ns = share(ctx, name="test")
    return leaf_type(namespace=ns, **kwargs), ctx


def test_travel_correction_acts_only_while_walking() -> None:
    seen: list[np.ndarray] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs)
        return np.array([0.25, -0.5, 2.0, 0.3])  # turn beyond 1 is clipped

    step, ctx = _leaf_ctx(StepTo)
    ctx.percept = _percept()
    ctx.plan_step = ("move", (11, 20, 30))
    ctx.goals = frozenset({(14, 20, 30)})
    ctx.commands.move, ctx.commands.strafe, ctx.commands.pitch = 0.8, 0.1, 0.4
    correction = TravelCorrection(policy)
    correction.apply(step, ctx, elapsed=1)
    assert len(seen) == 1 and seen[0].shape == (OBS_DIM,)
    np.testing.assert_allclose(seen[0][-4:], [0.8, 0.1, 0.0, -0.5])  # μ(s), jump off
    cmd = ctx.commands
    assert (cmd.move, cmd.strafe, cmd.turn, cmd.jump, cmd.pitch) == (0.25, -0.5, 1.0, True, 0.4)
    assert correction.last is not None
    np.testing.assert_allclose(correction.last, [0.25 - 0.8, -0.5 - 0.1, 1.0, 0.8])

    wait, ctx2 = _leaf_ctx(AtDestination)  # another leaf runs: its commands stand
    ctx2.percept, ctx2.plan_step = ctx.percept, ctx.plan_step
    ctx2.commands.move = 0.8
    correction.apply(wait, ctx2, elapsed=1)
    assert len(seen) == 1 and ctx2.commands.move == 0.8 and correction.last is None


@pytest.mark.parametrize("left", [set(), {"near"}])
def test_drop_nearby_leaves_what_a_correction_left(left: set[str]) -> None:
    leaf, ctx = _leaf_ctx(ChooseDrop, names=("log", "cobblestone"))
    ctx.percept = _percept(
        _item("log", 1.0, 0.0, 0.0, "near"), _item("cobblestone", 2.0, 0.0, 0.0, "next")
    )
    ctx.memory[SKIPPED_KEY] = left
    leaf.tick_once()  # type: ignore[attr-defined]
    chased = (11, 20, 30) if not left else (12, 20, 30)
    assert chased in ctx.goals


def _walking_under(purpose: str) -> tuple[object, Context]:
    """A "Step to cell" inside a travel sub-tree held by ``purpose`` (its activity: the
    walks of "Explore" are searching, the others travel)."""
    step, ctx = _leaf_ctx(StepTo)
    travel = py_trees.composites.Selector("Travel", memory=False, children=[step])
    py_trees.composites.Sequence(purpose, memory=False, children=[travel])
    ctx.percept = _percept()
    ctx.plan_step = ("move", (11, 20, 30))
    ctx.goals = frozenset({(14, 20, 30)})
    ctx.commands.move = 0.8
    return step, ctx


def test_travel_correction_kept_to_some_activities_leaves_the_other_walks_alone() -> None:
    seen: list[np.ndarray] = []

    def policy(obs: np.ndarray) -> np.ndarray:
        seen.append(obs)
        return np.array([0.25, 0.0, 0.0, -1.0])

    correction = TravelCorrection(policy, activities=frozenset({"searching"}))
    step, ctx = _walking_under("Mine log")
    correction.apply(step, ctx, elapsed=1)
    assert not seen and ctx.commands.move == 0.8 and correction.last is None
    step, ctx = _walking_under("Explore")
    correction.apply(step, ctx, elapsed=1)
    assert len(seen) == 1 and ctx.commands.move == 0.25 and correction.last is not None
    everywhere = TravelCorrection(policy)
    step, ctx = _walking_under("Mine log")
    everywhere.apply(step, ctx, elapsed=1)
    assert len(seen) == 2 and ctx.commands.move == 0.25
