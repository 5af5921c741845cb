"""The watchdog: ticked with scripted leaves (conditions that never pass, a step that
never lands, progress now and then), then with the real tree, whose "Re-plan" branch
takes over once it fires. The real-world check is in ``test_diamond_integration.py``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Optional

import py_trees
import pytest
from py_trees.common import Status
from py_trees.composites import Selector

from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.leaves.context import Context, Leaf, share
from minecraft.agent.leaves.percept import Percept
from minecraft.agent.leaves.recovery import RECOVER_KEY
from minecraft.agent.watchdog import Firing, Watchdog
from tests.minecraft.agent.test_diamond_tree import scene


class Scripted(Leaf):
    """A leaf whose status and commands come from a script."""

    def __init__(self, name: str, *, namespace: str, act: Callable[[Context], Status]) -> None:
        super().__init__(name, namespace=namespace)
        self.act = act

    def update(self) -> Status:
        return self.act(self.ctx)


def _tree(*acts: Callable[[Context], Status]) -> tuple[py_trees.trees.BehaviourTree, Context]:
    ctx = Context()
    ns = share(ctx, name="test")
    leaves = [Scripted(f"leaf {i}", namespace=ns, act=a) for i, a in enumerate(acts)]
    return py_trees.trees.BehaviourTree(Selector("root", memory=False, children=leaves)), ctx


def _run(
    tree: py_trees.trees.BehaviourTree,
    ctx: Context,
    dog: Watchdog,
    ticks: int,
    percept: Callable[[int], Percept],
) -> list[tuple[int, str]]:
    """Tick the tree ``ticks`` times as the episode runner does; the firings."""
    fired: list[tuple[int, str]] = []
    for t in range(ticks):
        ctx.percept = percept(t)
        ctx.commands.still()
        ctx.commands.once = []
        tree.tick()
        f: Optional[Firing] = dog.check(ctx)
        if f is not None:
            fired.append((f.tick, f.reason))
    return fired


def _still(t: int) -> Percept:
    return Percept(x=0.5, y=12.0, z=0.5, tick=t)


def _fail(ctx: Context) -> Status:
    return Status.FAILURE


def _walk(ctx: Context) -> Status:
    ctx.commands.move = 1.0  # pushing into a wall: commands, no movement
    return Status.RUNNING


def test_a_condition_that_never_passes_fires_after_idle_ticks() -> None:
    tree, ctx = _tree(_fail, _fail)
    fired = _run(tree, ctx, Watchdog(idle_ticks=50, stall_ticks=400), 160, _still)
    assert fired == [(50, "idle"), (100, "idle"), (150, "idle")]
    assert isinstance(ctx.memory[RECOVER_KEY], Firing)
    assert ctx.memory[RECOVER_KEY].plan == "wood"  # no wood held


def test_an_action_that_goes_nowhere_fires_after_stall_ticks() -> None:
    tree, ctx = _tree(_fail, _walk)
    ctx.target = (3, 12, 0)
    fired = _run(tree, ctx, Watchdog(idle_ticks=50, stall_ticks=400), 450, _still)
    assert fired == [(400, "stalled")]
    assert (3, 12, 0) in ctx.memory["given_up"] and ctx.target is None  # abandoned


@pytest.mark.parametrize("every", [1, 49])
def test_progress_keeps_it_quiet(every: int) -> None:
    """A new item every ``every`` ticks, or a new cell: no firing."""
    tree, ctx = _tree(_fail)

    def gaining(t: int) -> Percept:
        p = _still(t)
        p.inventory["cobblestone"] = t // every
        return p

    def moving(t: int) -> Percept:
        return Percept(x=0.5 + t // every, y=12.0, z=0.5, tick=t)

    dog = Watchdog(idle_ticks=50, stall_ticks=400)
    assert _run(tree, ctx, dog, 500, gaining) == []
    assert _run(tree, ctx, Watchdog(idle_ticks=50, stall_ticks=400), 500, moving) == []


def test_bad_thresholds_are_refused() -> None:
    with pytest.raises(ValueError, match="idle_ticks <= stall_ticks"):
        Watchdog(idle_ticks=100, stall_ticks=10)


def _tick_real(p: Percept, ticks: int, dog: Watchdog) -> tuple[dict[str, Status], Context]:
    root, ctx = build_tree()
    tree = py_trees.trees.BehaviourTree(root)
    for t in range(ticks):
        p.tick = t
        ctx.percept = p
        ctx.commands.still()
        ctx.commands.once = []
        tree.tick()
        dog.check(ctx)
    table = {n.name: n.status for n in root.iterate() if n.status != Status.INVALID}
    return table, ctx


def test_the_real_tree_shut_in_without_wood_re_plans_for_wood() -> None:
    """Walled in bedrock: nothing to plan, nothing acts; after the firing the tree's
    "Re-plan (wood)" branch is the one it works on."""
    walls = {(x, y, z): "bedrock" for x in (-1, 0, 1) for y in (63, 64, 65, 66)
             for z in (-1, 0, 1) if (x, z) != (0, 0) or y in (63, 66)}  # fmt: skip
    p = scene(inventory={"stone_pickaxe": 1, "furnace": 1}, blocks=walls)
    dog = Watchdog(idle_ticks=20, stall_ticks=100)
    table, ctx = _tick_real(p, 22, dog)  # fires after tick 20's decision
    assert dog.firings == 1
    assert table["Re-plan: wood?"] == Status.SUCCESS


def test_the_real_tree_with_wood_moves_elsewhere_then_goes_on() -> None:
    """Fired while carrying wood: the tree digs away along a fresh heading ("Re-plan
    (elsewhere)"); standing at its goal the re-plan ends and the quest resumes."""
    p = scene(inventory={"planks": 3, "stone_pickaxe": 1}, fill="stone", y=12)
    root, ctx = build_tree()
    tree = py_trees.trees.BehaviourTree(root)
    ctx.percept = p
    ctx.memory[RECOVER_KEY] = Firing(0, "stalled", "elsewhere")
    tree.tick()
    table = {n.name: n.status for n in root.iterate() if n.status != Status.INVALID}
    assert table["Re-plan: elsewhere?"] == Status.SUCCESS
    assert table["Break block"] == Status.RUNNING  # digging towards the new goals
    goal = next(iter(ctx.goals))
    assert abs(goal[0]) + abs(goal[2]) >= 6 and goal[1] == 12
    # Standing at the goal: the re-plan ends on this tick.
    ctx.percept = scene(inventory={"planks": 3, "stone_pickaxe": 1}, fill="air", y=12)
    ctx.percept.x, ctx.percept.z = goal[0] + 0.5, goal[2] + 0.5
    ctx.percept.tick = 5
    tree.tick()
    assert RECOVER_KEY not in ctx.memory
