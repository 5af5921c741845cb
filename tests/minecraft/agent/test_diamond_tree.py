"""The obtain-diamond tree's stages against scripted world states: a hand-built percept
goes on the blackboard, the tree is ticked once, and the status table and the commands
it wrote are checked. No server here (the integration test is in
``test_diamond_integration.py``)."""

from __future__ import annotations

from typing import Optional

import numpy as np
import py_trees
import pytest
from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.leaves.percept import RADIUS, SIDE, ItemSeen, Percept

AGENT = (0, 64, 0)  # the agent's feet cell in these scenes (x, z; y given per scene)


def scene(
    *,
    inventory: Optional[dict[str, int]] = None,
    blocks: Optional[dict[tuple[int, int, int], str]] = None,
    fill: str = "air",
    y: int = AGENT[1],
    **kw: object,
) -> Percept:
    """A percept: stone below the feet, ``fill`` around (the agent's cells kept free)."""
    ids = np.full((SIDE, SIDE, SIDE), B.ID[fill], dtype=np.uint8)
    ids[:RADIUS] = B.STONE_ID
    ids[RADIUS : RADIUS + 2, RADIUS, RADIUS] = B.AIR
    p = Percept(x=AGENT[0] + 0.5, y=float(y), z=AGENT[2] + 0.5, ids=ids, **kw)  # type: ignore
    for i, (item, n) in enumerate((inventory or {}).items()):
        p.inventory[item] = n
        p.slots[item] = [i]
    for cell, name in (blocks or {}).items():
        gx, gy, gz = p.to_grid(cell)
        p.ids[gy, gz, gx] = B.ID[name]
    return p


def tick(p: Percept, ticks: int = 1):
    root, ctx = build_tree()
    tree = py_trees.trees.BehaviourTree(root)
    for _ in range(ticks):
        ctx.percept = p
        ctx.commands.still()
        ctx.commands.once = []
        tree.tick()
    table: dict[str, list[Status]] = {}
    for node in root.iterate():
        if node.status != Status.INVALID:
            table.setdefault(node.name, []).append(node.status)
    return table, ctx


def status(table: dict[str, list[Status]], name: str) -> Status:
    """The status of the (last ticked) node called ``name``."""
    assert name in table, f"{name!r} was not ticked; ticked: {sorted(table)}"
    return table[name][-1]


def test_no_wood_walks_to_the_nearest_log() -> None:
    p = scene(blocks={(3, 64, 0): "log", (3, 65, 0): "log"})
    table, ctx = tick(p)
    assert status(table, "Enough wood?") == Status.FAILURE
    assert status(table, "Choose log") == Status.SUCCESS
    assert ctx.target == (3, 64, 0)
    assert status(table, "At destination?") == Status.FAILURE
    assert status(table, "Step to cell") == Status.RUNNING
    assert ctx.plan_step == ("move", (1, 64, 0))
    # Facing +z (yaw 0), east (+x) is to the left: strafe negative, no forward motion.
    assert ctx.commands.strafe < 0 and abs(ctx.commands.move) < 1e-9


def test_next_to_a_log_it_aims_and_digs() -> None:
    los = {"hitType": "block", "inRange": True, "blockX": 1, "blockY": 64, "blockZ": 0}
    p = scene(blocks={(1, 64, 0): "log", (1, 65, 0): "log"}, los=los)
    table, ctx = tick(p)
    assert status(table, "At destination?") == Status.SUCCESS
    assert status(table, "Mine target") == Status.RUNNING
    assert ctx.target == (1, 64, 0) and ctx.commands.attack
    assert ctx.commands.move == 0.0


def test_no_log_in_view_explores_the_surface() -> None:
    table, ctx = tick(scene())
    assert status(table, "Choose log") == Status.FAILURE
    assert status(table, "Explore (surface)") == Status.SUCCESS
    assert status(table, "Step to cell") == Status.RUNNING


@pytest.mark.parametrize(
    ("inventory", "craft"),
    [
        ({"log": 4}, "planks"),
        ({"log": 3, "planks": 4}, "crafting_table"),
        ({"log": 3, "crafting_table": 1, "planks": 2}, "stick"),
        ({"log": 2, "crafting_table": 1, "stick": 2, "planks": 3}, "wooden_pickaxe"),
        # The furnace (8 cobblestone) comes before the stone pickaxe (3): both need stone.
        ({"log": 2, "crafting_table": 1, "stick": 2, "cobblestone": 8, "wooden_pickaxe": 1},
         "furnace"),
        ({"log": 2, "crafting_table": 1, "stick": 2, "cobblestone": 3, "wooden_pickaxe": 1,
          "furnace": 1}, "stone_pickaxe"),
        # Smelting needs fuel: planks when there is no coal.
        ({"log": 2, "crafting_table": 1, "stick": 2, "furnace": 1, "stone_pickaxe": 1,
          "iron_ore": 1}, "planks"),
        # The planks to burn lie first among the fuels (else they are swapped there first).
        ({"planks": 1, "log": 2, "crafting_table": 1, "stick": 2, "furnace": 1,
          "stone_pickaxe": 1, "iron_ore": 1}, "iron_ingot"),
        ({"log": 2, "crafting_table": 1, "stick": 2, "furnace": 1, "stone_pickaxe": 1,
          "iron_ingot": 3}, "iron_pickaxe"),
    ],
)  # fmt: skip
def test_crafting_stages_follow_the_inventory(inventory: dict[str, int], craft: str) -> None:
    table, ctx = tick(scene(inventory=inventory))
    assert status(table, "Enough wood?") == Status.SUCCESS
    assert status(table, f"Craft {craft}") == Status.RUNNING
    assert ctx.commands.once == [f"craft {craft}"]


def test_the_next_craft_follows_when_the_item_appears() -> None:
    root, ctx = build_tree()
    tree = py_trees.trees.BehaviourTree(root)
    ctx.percept = scene(inventory={"log": 4})
    tree.tick()
    assert ctx.commands.once == ["craft planks"]
    ctx.percept = scene(inventory={"log": 3, "planks": 4})  # the world crafted them
    ctx.commands.once = []
    tree.tick()
    assert ctx.commands.once == ["craft crafting_table"]


def test_with_a_wooden_pickaxe_it_mines_stone() -> None:
    los = {"hitType": "block", "inRange": True, "blockX": 0, "blockY": 63, "blockZ": 0}
    inv = {"log": 2, "crafting_table": 1, "stick": 2, "wooden_pickaxe": 1}
    table, ctx = tick(scene(inventory=inv, los=los, pitch=90.0))
    assert status(table, "Choose stone/cobblestone") == Status.SUCCESS
    assert ctx.target is not None and ctx.target[1] < 64
    assert status(table, "Mine target") == Status.RUNNING
    # The pickaxe goes in hand before digging.
    assert ctx.commands.once == ["hotbar.4 1"] and not ctx.commands.attack


def test_iron_pickaxe_high_up_descends_straight_down_when_safe() -> None:
    inv = {"log": 2, "iron_pickaxe": 1}
    table, ctx = tick(scene(inventory=inv, fill="stone", y=60))
    assert status(table, "Choose diamond_ore") == Status.FAILURE
    assert status(table, "Above y=12?") == Status.SUCCESS
    assert status(table, "Descend to y=12") == Status.SUCCESS
    assert ctx.plan_step == ("destroy", (0, 59, 0))


def test_descent_avoids_a_shaft_over_lava() -> None:
    inv = {"log": 2, "iron_pickaxe": 1}
    lava = {(0, 62, 0): "lava", (0, 61, 0): "lava"}
    lava.update({(dx, 62, dz): "lava" for dx in (-1, 1) for dz in (-1, 0, 1)})
    table, ctx = tick(scene(inventory=inv, fill="stone", blocks=lava))
    assert ctx.plan_step is not None
    assert ctx.plan_step != ("destroy", (0, 63, 0))  # the block above the lava stays


def test_sees_a_diamond_and_skips_one_touching_lava() -> None:
    inv = {"log": 2, "iron_pickaxe": 1}
    ores = {(2, 11, 0): "diamond_ore", (2, 10, 0): "lava", (-3, 12, 0): "diamond_ore"}
    table, ctx = tick(scene(inventory=inv, fill="stone", y=12, blocks=ores))
    assert status(table, "Choose diamond_ore") == Status.SUCCESS
    assert ctx.target == (-3, 12, 0)
    assert status(table, "Break block") == Status.RUNNING  # digging towards it


def test_in_water_it_swims_out_first() -> None:
    p = scene(blocks={AGENT: "water", (0, 65, 0): "water"}, inventory={"log": 4})
    table, ctx = tick(p)
    assert status(table, "In water or lava?") == Status.SUCCESS
    assert status(table, "Escape liquid") == Status.RUNNING
    assert status(table, "Survive") == Status.RUNNING
    assert ctx.commands.jump and "Quest" not in table


def test_hungry_with_food_eats() -> None:
    p = scene(inventory={"apple": 1, "log": 4}, food=10, selected=0)
    table, ctx = tick(p)
    assert status(table, "Hungry and have food?") == Status.SUCCESS
    assert status(table, "Eat") == Status.RUNNING
    assert ctx.commands.use  # the apple is in the selected slot 0


def test_picks_up_a_nearby_drop_before_going_on() -> None:
    p = scene(inventory={"log": 4})
    p.items.append(ItemSeen("log", 2.5, 64.0, 0.5, 1, "17"))
    table, ctx = tick(p)
    assert status(table, "Drop nearby?") == Status.SUCCESS
    assert ctx.plan_step == ("move", (1, 64, 0))
    assert "Quest" not in table


def test_underground_without_wood_mines_coal_for_fuel() -> None:
    inv = {"crafting_table": 1, "stick": 4, "furnace": 1, "stone_pickaxe": 1, "iron_ore": 2}
    table, ctx = tick(scene(inventory=inv, fill="stone", y=30, blocks={(2, 30, 0): "coal_ore"}))
    assert status(table, "Enough wood?") == Status.SUCCESS  # no trees down here
    assert status(table, "Choose coal_ore") == Status.SUCCESS
    assert ctx.target == (2, 30, 0)


@pytest.mark.parametrize("hold, kept", [(1, True), (6, False)])
def test_in_the_air_a_slow_client_drops_a_step_planned_long_ago(hold: int, kept: bool) -> None:
    """Every tick, the step is kept through the air; a slow client keeps it only for a
    jump's air time after it was planned (a step from before a fall would steer it to
    jump forever)."""
    inv = {"log": 2, "iron_pickaxe": 1}
    stale = ("move", (0, 70, 0))  # far above: steering towards it jumps
    root, ctx = build_tree()
    ctx.percept = scene(inventory=inv, fill="stone", y=60.4, tick=500)  # mid-air
    ctx.plan_step, ctx.memory["planned_tick"] = stale, 100
    ctx.commands.hold = hold
    py_trees.trees.BehaviourTree(root).tick()
    assert (ctx.plan_step == stale) is kept
    if not kept:
        assert ctx.memory["planned_tick"] == 500


@pytest.mark.parametrize("hold", [1, 6])
def test_a_slow_client_aims_over_its_hold(hold: int) -> None:
    """The turn that closes an error of 27 degrees: all of it in one tick (clipped at
    full speed, 9 degrees a tick), or a sixth of full speed for each of 6 held ticks."""
    from minecraft.agent.leaves import control
    from minecraft.agent.leaves.context import Commands

    cmd = Commands(hold=hold)
    p = Percept(x=0.5, y=64.0, z=0.5, yaw=0.0, pitch=0.0)
    # A point 27 degrees to the left of +z, at eye height.
    a = np.radians(27.0)
    err = control.aim(p, (0.5 - 10 * np.sin(a), 64.0 + control.EYE, 0.5 + 10 * np.cos(a)), cmd)
    assert err == pytest.approx(27.0)
    assert cmd.turn == pytest.approx(1.0 if hold == 1 else 27.0 / (9.0 * 6))
    # One block to walk: full speed covers 0.216 a tick, 1.3 in 6 ticks.
    control.steer(p, (0, 64, 1), cmd)
    assert cmd.move == pytest.approx(1.0 if hold == 1 else 1.0 / (control.WALK_PER_TICK * 6))


@pytest.mark.parametrize(
    "depth, item_x, attacks",
    [(1, 0.5, True), (1, 3.5, False), (6, 0.5, False)],
    ids=["on-the-block", "elsewhere", "out-of-reach"],
)
def test_digging_reaches_through_an_item_lying_on_the_block(
    depth: int, item_x: float, attacks: bool
) -> None:
    """Malmo's ray observation stops at a dropped item, hands do not: aimed straight down at
    the block underfoot with the last block's drop lying on it, the tree keeps digging;
    an item lying anywhere else in the ray, or on a block out of reach, still stops it."""
    from minecraft.agent.leaves.context import Commands
    from minecraft.agent.leaves.travel import break_block

    top = AGENT[1] - depth + 1
    los = {"hitType": "item", "type": "cobblestone", "x": item_x, "y": float(top), "z": 0.5}
    p = scene(inventory={"stone_pickaxe": 1}, yaw=0.0, pitch=90.0, los=los)
    cmd = Commands()
    assert break_block(p, (AGENT[0], AGENT[1] - depth, AGENT[2]), cmd, {}) == Status.RUNNING
    assert cmd.attack is attacks


def test_smelting_puts_the_coal_first_so_the_sticks_are_not_burnt() -> None:
    """SimpleCraft burns fuel from the first slot up: the sticks in slot 0 would burn
    before the coal in slot 3 (and the next iron pickaxe would find none)."""
    inv = {"stick": 2, "planks": 1, "furnace": 1, "coal": 1, "stone_pickaxe": 1, "iron_ore": 1}
    table, ctx = tick(scene(inventory=inv, fill="stone", y=12))
    assert status(table, "Craft iron_ingot") == Status.RUNNING
    assert ctx.commands.once == ["swapInventoryItems 0 3"]


def test_underground_without_wood_for_sticks_it_climbs_to_the_surface() -> None:
    """A worn-out iron pickaxe, ingots for a new one, no wood left at y=12: the tree
    digs a staircase up (the trees are on the surface) instead of waiting on a log."""
    inv = {"furnace": 1, "stone_pickaxe": 1, "iron_ingot": 3, "cobblestone": 40}
    table, ctx = tick(scene(inventory=inv, fill="stone", y=12))
    assert status(table, "Has 1 log?") == Status.FAILURE
    assert status(table, "Underground?") == Status.SUCCESS
    assert status(table, "Ascend") == Status.SUCCESS
    assert status(table, "Break block") == Status.RUNNING
    assert ctx.plan_step is not None and ctx.plan_step[0] == "destroy"
    assert ctx.goals and min(g[1] for g in ctx.goals) > 12


def test_gravel_fallen_into_its_feet_cell_is_dug_out_first() -> None:
    """A body inside a block neither falls nor walks, and A* cannot start there."""
    los = {"hitType": "block", "inRange": True, "blockX": 0, "blockY": 12, "blockZ": 0}
    inv = {"planks": 3, "stone_pickaxe": 1}
    p = scene(inventory=inv, fill="stone", y=12, blocks={(0, 12, 0): "gravel"}, los=los)
    p.pitch = 90.0
    table, ctx = tick(p)
    assert status(table, "Inside a block?") == Status.SUCCESS
    assert status(table, "Dig out") == Status.RUNNING
    assert ctx.commands.attack and "Quest" not in table
