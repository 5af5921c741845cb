"""World behaviour a player would notice, driven through the protocol: crafting with
Minecraft's quantities, tools, mining and pick-up, collisions, jumps, falls, hazards,
and the grid observation's order."""

from __future__ import annotations

import math

import numpy as np
import pytest

from minecraft import blocks as B
from minecraft.sim import worldgen
from minecraft.sim.crafting import CraftState, craft
from minecraft.sim.inventory import Inventory
from tests.minecraft.conftest import GROUND


def _inv(**items: int) -> Inventory:
    inv = Inventory()
    for k, v in items.items():
        inv.add(k, v)
    return inv


def _counts(info: dict) -> dict[str, int]:
    out: dict[str, int] = {}
    for s in info["inventory"]:
        out[s["type"]] = out.get(s["type"], 0) + s["quantity"]
    return out


@pytest.mark.parametrize(
    ("have", "make", "ok", "after"),
    [
        ({"log": 1}, "planks", True, {"planks": 4}),
        ({"planks": 2}, "stick", True, {"stick": 4}),
        ({"planks": 4}, "crafting_table", True, {"crafting_table": 1}),
        # SimpleCraft, as Malmo's: 3x3 recipes need no crafting table, smelting no furnace.
        ({"planks": 3, "stick": 2}, "wooden_pickaxe", True, {"wooden_pickaxe": 1}),
        ({"planks": 2, "stick": 2}, "wooden_pickaxe", False, {"planks": 2, "stick": 2}),
        ({"cobblestone": 3, "stick": 2, "crafting_table": 1}, "stone_pickaxe", True,
         {"stone_pickaxe": 1, "crafting_table": 1}),
        ({"cobblestone": 7, "crafting_table": 1}, "furnace", False,
         {"cobblestone": 7, "crafting_table": 1}),
        ({"cobblestone": 8}, "furnace", True, {"furnace": 1}),
        ({"iron_ore": 1, "coal": 1}, "iron_ingot", True, {"iron_ingot": 1}),
        ({"iron_ore": 1, "furnace": 1}, "iron_ingot", False, {"iron_ore": 1, "furnace": 1}),
        ({"iron_ore": 1, "furnace": 1, "planks": 1}, "iron_ingot", True,
         {"iron_ingot": 1, "furnace": 1}),
        ({"iron_ingot": 3, "stick": 2}, "iron_pickaxe", True, {"iron_pickaxe": 1}),
    ],
)  # fmt: skip
def test_recipes(have: dict, make: str, ok: bool, after: dict) -> None:
    inv = _inv(**have)
    assert craft(inv, CraftState(), make)[0] is ok
    assert {k: inv.count(k) for k in set(have) | set(after) if inv.count(k)} == after


def test_one_coal_smelts_eight() -> None:
    inv, st = _inv(iron_ore=9, coal=1, furnace=1), CraftState()
    results = [craft(inv, st, "iron_ingot")[0] for _ in range(9)]
    assert results == [True] * 8 + [False]
    assert inv.count("iron_ingot") == 8


def test_smelting_burns_fuel_from_the_first_slot_up() -> None:
    # As Malmo: whatever fuel comes first burns, here the sticks before the coal.
    inv, st = _inv(stick=3, coal=1, iron_ore=1), CraftState()
    assert craft(inv, st, "iron_ingot") == (True, "", [("iron_ore", 1)])
    assert (inv.count("stick"), inv.count("coal"), inv.count("iron_ingot")) == (1, 1, 1)


@pytest.mark.parametrize(
    ("block", "tool", "ticks", "drops"),
    [
        ("stone", None, 150, False),
        ("stone", "wooden_pickaxe", 23, True),
        ("log", None, 60, True),
        ("dirt", None, 15, True),
        ("iron_ore", "wooden_pickaxe", 150, False),
        ("iron_ore", "stone_pickaxe", 23, True),
        ("diamond_ore", "stone_pickaxe", 75, False),
        ("diamond_ore", "iron_pickaxe", 15, True),
        ("bedrock", "iron_pickaxe", math.inf, False),
    ],
)
def test_mining_times_and_tool_requirements(block, tool, ticks, drops) -> None:
    bid = B.ID[block]
    assert B.ticks_to_break(bid, tool) == ticks
    assert B.can_harvest(bid, tool) is drops


def test_crafting_through_the_protocol(sync_client) -> None:
    c = sync_client(inventory=((0, "log", 3),))
    crafts = ["planks"] * 3 + ["stick", "crafting_table", "wooden_pickaxe"]
    r = c.step("\n".join(f"craft {x}" for x in crafts))
    # 3 logs -> 12 planks; 2 -> 4 sticks; 4 -> table; 3 planks + 2 sticks -> pickaxe (with
    # the table in the inventory).
    assert _counts(r.info) == {"stick": 2, "crafting_table": 1, "wooden_pickaxe": 1, "planks": 3}


def test_mining_and_pick_up(sync_client) -> None:
    rewards = (
        '<RewardForCollectingItem><Item type="cobblestone" reward="5"/></RewardForCollectingItem>'
    )
    c = sync_client(
        decorators='<DrawBlock x="0" y="4" z="2" type="stone"/>',
        inventory=((0, "wooden_pickaxe", 1),),
        rewards=rewards,
    )
    r = c.step("setPitch 20")
    assert r.info["LineOfSight"]["type"] == "stone"
    total, ticks = 0.0, 0
    while r.info.get("LineOfSight", {}).get("type") == "stone":
        r = c.step("attack 1")
        ticks += 1
        assert ticks < 40
    assert 22 <= ticks <= 25  # 23 ticks with a wooden pickaxe, ±1 for the command tick
    for _ in range(30):
        r = c.step("attack 0\nmove 1")
        total += r.reward
        if _counts(r.info).get("cobblestone"):
            break
    assert _counts(r.info)["cobblestone"] == 1
    assert total == 5.0


def test_walls_stop_and_one_block_can_be_jumped(sync_client) -> None:
    wall = '<DrawCuboid x1="-2" y1="4" z1="3" x2="2" y2="5" z2="3" type="stone"/>'
    c = sync_client(decorators=wall)
    for _ in range(40):
        r = c.step("move 1")
    assert r.info["ZPos"] == pytest.approx(3 - 0.3)  # pressed against the 2-high wall
    for _ in range(20):
        r = c.step("move 1\njump 1")
    assert r.info["ZPos"] < 3  # cannot jump two blocks
    step = '<DrawCuboid x1="-2" y1="4" z1="3" x2="2" y2="4" z2="6" type="stone"/>'
    c2 = sync_client(decorators=step)
    for _ in range(30):
        r = c2.step("move 1\njump 1")
    for _ in range(15):
        r = c2.step("move 0\njump 0")
    assert r.info["YPos"] == GROUND + 1 and r.info["ZPos"] > 3


def test_fall_damage(sync_client) -> None:
    c = sync_client(placement=(0.5, GROUND + 10, 0.5))
    for _ in range(40):
        r = c.step("")
    assert r.info["YPos"] == GROUND
    assert r.info["Life"] == 20 - 7  # ceil(10 - 3)


def test_lava_hurts_and_can_end_the_mission(sync_client) -> None:
    quit_lava = (
        '<AgentQuitFromTouchingBlockType><Block type="lava"/></AgentQuitFromTouchingBlockType>'
    )
    c = sync_client(decorators='<DrawBlock x="0" y="3" z="2" type="lava"/>', rewards=quit_lava)
    r = c.step("")
    for _ in range(20):
        r = c.step("move 1")
        if r.done:
            break
    assert r.done


def test_drowning_uses_air(sync_client) -> None:
    pool = '<DrawCuboid x1="-3" y1="4" z1="-3" x2="3" y2="8" z2="3" type="water"/>'
    c = sync_client(decorators=pool)
    r = c.step("")
    for _ in range(30):
        r = c.step("")
    assert r.info["Air"] < 300


def test_grid_order_is_x_then_z_then_y(sync_client) -> None:
    deco = ('<DrawBlock x="1" y="4" z="0" type="gold_ore"/>'
            '<DrawBlock x="0" y="4" z="1" type="iron_ore"/>'
            '<DrawBlock x="0" y="5" z="0" type="diamond_ore"/>')  # fmt: skip
    c = sync_client(decorators=deco, placement=(0.5, 6.0, 0.5), grid_radius=2)
    r = c.step("")
    cube = r.info["cube"]
    assert len(cube) == 125

    def at(x: int, y: int, z: int) -> str:
        # Relative to the agent's block; the grid spans -2..2 on each axis.
        return cube[(y + 2) * 25 + (z + 2) * 5 + (x + 2)]

    pos_y = math.floor(r.info["YPos"])
    assert pos_y == 6  # standing on the diamond_ore placed at y=5
    assert at(0, -1, 0) == "diamond_ore"
    assert at(1, -2, 0) == "gold_ore"
    assert at(0, -2, 1) == "iron_ore"


def test_default_worlds_are_seeded_and_minecraft_like() -> None:
    a, b = worldgen.generate(3), worldgen.generate(3)
    assert np.array_equal(a.blocks, b.blocks)
    assert not np.array_equal(a.blocks, worldgen.generate(4).blocks)
    blocks = a.blocks
    assert (blocks[:, 0, :] == B.BEDROCK).all()
    ys = np.nonzero(blocks == B.ID["diamond_ore"])[1]
    assert len(ys) > 20 and ys.max() <= 15 + 7  # veins start at y <= 15
    ix, iz = int(a.spawn[0]) - a.x0, int(a.spawn[2]) - a.z0
    near = blocks[max(ix - 12, 0) : ix + 12, :, max(iz - 12, 0) : iz + 12]
    assert (near == B.ID["log"]).sum() >= 8  # trees a short walk from spawn
    assert (blocks[:, : int(a.spawn[1]) - 5, :] == B.STONE_ID).mean() > 0.5


def test_the_agents_of_one_mission_share_blocks_items_and_animals() -> None:
    from pathlib import Path

    from minecraft.malmo.mission import parse_mission
    from minecraft.malmo.roles import role_mission
    from minecraft.sim.world import World

    xml = (Path(__file__).parents[1] / "compat" / "missions" / "two_agents_shared.xml").read_text()
    host = World(parse_mission(role_mission(xml, 0).xml), 5)
    guest = World(parse_mission(role_mission(xml, 1).xml), 5, share=host)
    assert guest.others[0] is host.player and host.others[0] is guest.player
    assert guest.entity_uuid(guest.player_uid) != host.entity_uuid(host.player_uid)
    version = host.version
    guest.set(3, 4, 3, B.ID["stone"])  # the guest builds; the host sees it
    assert host.get(3, 4, 3) == B.ID["stone"] and host.version == version + 1
    # An item dropped at the guest's feet: the host's tick moves it (once a tick, not
    # once per agent), the guest's tick picks it up.
    host.drop("dirt", 2, 0.5, 5.0, 4.5, delay=2, still=True)
    host.tick([])
    guest.tick([])
    assert host.items[0].body.y < 5.0 and host.items[0].age == 1
    host.tick([])
    guest.tick([])
    assert host.items == [] and guest.player.inventory.count("dirt") == 2
    assert host.player.inventory.count("dirt") == 1  # its own start inventory only


def test_diamond_keep_turns_whole_veins_to_stone_and_nothing_else() -> None:
    full = worldgen.generate(3)
    thin = worldgen.generate(3, diamond_keep=0.25)
    ore = B.ID["diamond_ore"]
    veins = {tuple(v) for v in worldgen.veins(full.blocks, ore)}
    kept = {tuple(v) for v in worldgen.veins(thin.blocks, ore)}
    assert kept < veins  # whole veins kept, none cut
    assert 0.1 < len(kept) / len(veins) < 0.45
    changed = full.blocks != thin.blocks
    assert (full.blocks[changed] == ore).all() and (thin.blocks[changed] == B.STONE_ID).all()
    assert np.array_equal(thin.blocks, worldgen.generate(3, diamond_keep=0.25).blocks)
    assert not (worldgen.generate(3, diamond_keep=0.0).blocks == ore).any()
    with pytest.raises(ValueError, match="diamond_keep must be within"):
        worldgen.generate(3, diamond_keep=1.5)


def test_diamond_keep_reaches_the_world_from_the_server_and_the_mission() -> None:
    """The server's setting, and the mission's generatorOptions over it."""
    from minecraft.malmo.client import MalmoClient
    from minecraft.malmo.mission import MissionError, parse_mission
    from minecraft.malmo.mission_xml import obtain_diamond
    from minecraft.sim.server import WorldServer
    from minecraft.sim.timing import IDEAL

    ore = B.ID["diamond_ore"]
    with WorldServer(port=0, seed=3, timing=IDEAL, diamond_keep=0.0) as server:
        client = MalmoClient("127.0.0.1", server.port, synchronous=True, seed=3, timeout=10)
        for xml, diamonds in ((obtain_diamond(seed=3), False),
                              (obtain_diamond(seed=3, diamond_keep=1.0), True)):  # fmt: skip
            client.init(xml)
            client.reset()
            world = server.inst.world
            assert world is not None and bool((world.blocks == ore).any()) is diamonds
        client.close()
    bad = obtain_diamond(seed=3, diamond_keep=0.5).replace("0.5}", "2}")
    with pytest.raises(MissionError, match="diamondKeep must be a number within"):
        parse_mission(bad)
    with pytest.raises(ValueError, match="diamond_keep must be within"):
        WorldServer(port=0, diamond_keep=-0.1)


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_serve_refuses_a_diamond_keep_outside_0_1_in_one_line() -> None:
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    cmd = [sys.executable, "-m", "minecraft.cli", "minecraft", "serve", "--port", "0",
           "--diamond-keep", "1.5"]  # fmt: skip
    out = subprocess.run(cmd, cwd=root, capture_output=True, text=True, timeout=60)
    assert out.returncode != 0
    assert (
        out.stderr.strip() == "graft minecraft serve: --diamond-keep must be within [0, 1], got 1.5"
    )
