"""Block and item tables of the simulated world, with Minecraft 1.11 names and numbers.

Every Minecraft 1.11 block type has an entry: the first ones are modelled in full, the
rest (``approximate_blocks``) are drawn and observed under their own name but behave as
the simplest block of their kind.

Blocks are stored as small integer ids (``uint8``) in the voxel array; every per-block
property is a numpy lookup table indexed by that id, so physics and observations can
work on whole slices at once. Mining follows Minecraft's formula: each tick of holding
attack adds ``speed / hardness / (30 if harvestable else 100)`` to the damage of the
targeted block, and it breaks at 1.0 (``ticks_to_break``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from minecraft import approximate_blocks
from minecraft.names import numeric_id

# Harvest levels as in Minecraft: the lowest tool tier that makes a block drop anything.
HAND, WOOD, STONE, IRON, DIAMOND = -1, 0, 1, 2, 3


@dataclass(frozen=True)
class Block:
    """One block type.

    Attributes:
        name: Minecraft 1.11 registry name (``"stone"``), also the grid observation name.
        hardness: Minecraft hardness; ``inf`` cannot be broken, 0 breaks instantly.
        tool: tool family that mines it fast (``"pickaxe"``, ``"axe"``, ``"shovel"``, "").
        level: minimum harvest level of that tool for a drop (``HAND`` = none needed).
        drop: item dropped when harvested ("" drops nothing).
        drop_count: how many items drop.
        solid: collides with players, mobs and items.
        liquid: water or lava (never targeted by the crosshair).
        colour: RGB colour used by the renderer.
        mc_id: Minecraft numeric id (used by FlatWorldGenerator strings).
    """

    name: str
    hardness: float
    tool: str
    level: int
    drop: str
    drop_count: int
    solid: bool
    liquid: bool
    colour: tuple[int, int, int]
    mc_id: int


INF = math.inf
_B = Block
BLOCKS: tuple[Block, ...] = (
    _B("air", 0.0, "", HAND, "", 0, False, False, (0, 0, 0), 0),
    _B("stone", 1.5, "pickaxe", WOOD, "cobblestone", 1, True, False, (125, 125, 125), 1),
    _B("grass", 0.6, "shovel", HAND, "dirt", 1, True, False, (95, 159, 53), 2),
    _B("dirt", 0.5, "shovel", HAND, "dirt", 1, True, False, (134, 96, 67), 3),
    _B("cobblestone", 2.0, "pickaxe", WOOD, "cobblestone", 1, True, False, (100, 100, 100), 4),
    _B("planks", 2.0, "axe", HAND, "planks", 1, True, False, (162, 130, 78), 5),
    _B("bedrock", INF, "", HAND, "", 0, True, False, (40, 40, 40), 7),
    _B("water", INF, "", HAND, "", 0, False, True, (47, 67, 244), 9),
    _B("flowing_water", INF, "", HAND, "", 0, False, True, (60, 85, 244), 8),
    _B("lava", INF, "", HAND, "", 0, False, True, (207, 92, 15), 11),
    _B("flowing_lava", INF, "", HAND, "", 0, False, True, (230, 110, 20), 10),
    _B("sand", 0.5, "shovel", HAND, "sand", 1, True, False, (219, 207, 163), 12),
    _B("gravel", 0.6, "shovel", HAND, "gravel", 1, True, False, (136, 126, 126), 13),
    _B("log", 2.0, "axe", HAND, "log", 1, True, False, (102, 81, 51), 17),
    _B("leaves", 0.2, "", HAND, "", 0, True, False, (48, 110, 30), 18),
    _B("coal_ore", 3.0, "pickaxe", WOOD, "coal", 1, True, False, (60, 60, 60), 16),
    _B("iron_ore", 3.0, "pickaxe", STONE, "iron_ore", 1, True, False, (175, 142, 119), 15),
    _B("gold_ore", 3.0, "pickaxe", IRON, "gold_ore", 1, True, False, (230, 210, 90), 14),
    _B("diamond_ore", 3.0, "pickaxe", IRON, "diamond", 1, True, False, (93, 236, 245), 56),
    _B("redstone_ore", 3.0, "pickaxe", IRON, "redstone", 4, True, False, (170, 30, 30), 73),
    _B("lapis_ore", 3.0, "pickaxe", STONE, "dye", 5, True, False, (30, 60, 170), 21),
    _B("crafting_table", 2.5, "axe", HAND, "crafting_table", 1, True, False, (120, 75, 40), 58),
    _B("furnace", 3.5, "pickaxe", WOOD, "furnace", 1, True, False, (90, 90, 90), 61),
    _B("obsidian", 50.0, "pickaxe", DIAMOND, "obsidian", 1, True, False, (20, 18, 30), 49),
    _B("glass", 0.3, "", HAND, "", 0, True, False, (200, 230, 235), 20),
    _B("torch", 0.0, "", HAND, "torch", 1, False, False, (255, 220, 80), 50),
)
# Every other Minecraft 1.11 block, appended so the ids above never change.
_LEVELS = {"hand": HAND, "wood": WOOD, "stone": STONE, "iron": IRON}
BLOCKS += tuple(
    _B(name, hardness, tool, _LEVELS[level], drop, count, solid, False, colour, numeric_id(name))
    for name, hardness, tool, level, drop, count, solid, colour, _ in approximate_blocks.rows()
)

NAMES: tuple[str, ...] = tuple(b.name for b in BLOCKS)
ID: dict[str, int] = {b.name: i for i, b in enumerate(BLOCKS)}
MC_ID: dict[int, int] = {b.mc_id: i for i, b in enumerate(BLOCKS)}

AIR = ID["air"]
STONE_ID = ID["stone"]
BEDROCK = ID["bedrock"]
WATER = ID["water"]
FLOWING_WATER = ID["flowing_water"]
LAVA = ID["lava"]
FLOWING_LAVA = ID["flowing_lava"]

# Lookup tables indexed by block id.
SOLID = np.array([b.solid for b in BLOCKS], dtype=bool)
LIQUID = np.array([b.liquid for b in BLOCKS], dtype=bool)
IS_WATER = np.zeros(len(BLOCKS), dtype=bool)
IS_WATER[[WATER, FLOWING_WATER]] = True
IS_LAVA = np.zeros(len(BLOCKS), dtype=bool)
IS_LAVA[[LAVA, FLOWING_LAVA]] = True
COLOURS = np.array([b.colour for b in BLOCKS], dtype=np.float32)
# Blocks a ray stops at, for the renderer (liquids are drawn, air and torches are not).
OPAQUE = SOLID | LIQUID
# Blocks the crosshair can target (what ObservationFromRay reports and attack hits).
TARGETABLE = np.array([b.name not in ("air",) and not b.liquid for b in BLOCKS], dtype=bool)
# JSON-quoted names, for building grid observations without json.dumps per element.
QUOTED = np.array(['"' + n + '"' for n in NAMES], dtype=object)
FALLS = np.zeros(len(BLOCKS), dtype=bool)
FALLS[[ID["sand"], ID["gravel"]]] = True


@dataclass(frozen=True)
class Tool:
    """A tool item: its family, tier and Minecraft numbers."""

    kind: str
    level: int
    speed: float
    durability: int
    damage: float


TOOLS: dict[str, Tool] = {}
for _tier, _lvl, _spd, _dur, _base in (
    ("wooden", WOOD, 2.0, 59, 0.0),
    ("stone", STONE, 4.0, 131, 1.0),
    ("iron", IRON, 6.0, 250, 2.0),
    ("diamond", DIAMOND, 8.0, 1561, 3.0),
    ("golden", WOOD, 12.0, 32, 0.0),
):
    TOOLS[f"{_tier}_pickaxe"] = Tool("pickaxe", _lvl, _spd, _dur, 2.0 + _base)
    TOOLS[f"{_tier}_axe"] = Tool("axe", _lvl, _spd, _dur, 7.0 + _base)
    TOOLS[f"{_tier}_shovel"] = Tool("shovel", _lvl, _spd, _dur, 2.5 + _base)
    TOOLS[f"{_tier}_sword"] = Tool("sword", _lvl, 1.5, _dur, 4.0 + _base)

# Food: item -> (food points, saturation), Minecraft 1.11 values.
FOOD: dict[str, tuple[int, float]] = {
    "apple": (4, 2.4),
    "porkchop": (3, 1.8),
    "cooked_porkchop": (8, 12.8),
    "beef": (3, 1.8),
    "cooked_beef": (8, 12.8),
    "bread": (5, 6.0),
}

# Furnace fuel: item -> number of items it smelts.
FUEL: dict[str, float] = {
    "coal": 8.0,
    "log": 1.5,
    "planks": 1.5,
    "crafting_table": 1.5,
    "stick": 0.5,
    "wooden_pickaxe": 1.0,
    "wooden_axe": 1.0,
    "wooden_shovel": 1.0,
    "wooden_sword": 1.0,
}

# Items whose name is a block and that can be placed with `use`.
# Blocks no item places (technical states, crops, wires, the halves of a double slab).
_NO_ITEM = frozenset(
    """air grass leaves leaves2 piston_head piston_extension double_stone_slab
    double_stone_slab2 double_wooden_slab purpur_double_slab redstone_wire wheat carrots
    potatoes beetroots cocoa pumpkin_stem melon_stem standing_sign wall_sign standing_banner
    wall_banner lit_furnace lit_redstone_ore lit_redstone_lamp lit_pumpkin
    unlit_redstone_torch unpowered_repeater powered_repeater unpowered_comparator
    powered_comparator daylight_detector_inverted tripwire farmland grass_path frosted_ice
    end_portal_frame mob_spawner command_block repeating_command_block chain_command_block
    structure_block structure_void barrier monster_egg""".split()
)
PLACEABLE: frozenset[str] = frozenset(
    n for n in NAMES if n not in _NO_ITEM and not BLOCKS[ID[n]].liquid
)


def max_stack(item: str) -> int:
    """Stack size of an item: 1 for tools, 64 otherwise."""
    return 1 if item in TOOLS else 64


def block_id(name: str) -> int:
    """Block id for a Minecraft name, accepting a ``minecraft:`` prefix.

    Raises:
        KeyError: with the list of known names when the block is not simulated.
    """
    key = name.removeprefix("minecraft:")
    try:
        return ID[key]
    except KeyError:
        raise KeyError(f"unknown block {name!r}; simulated blocks: {', '.join(NAMES)}") from None


def can_harvest(block: int, held: Optional[str]) -> bool:
    """Whether breaking ``block`` with ``held`` in hand drops its item."""
    b = BLOCKS[block]
    if b.hardness == INF:
        return False
    if b.level == HAND:
        return True
    tool = TOOLS.get(held or "")
    return tool is not None and tool.kind == b.tool and tool.level >= b.level


def break_progress_per_tick(block: int, held: Optional[str]) -> float:
    """Fraction of the block broken per tick of holding attack (Minecraft's formula)."""
    b = BLOCKS[block]
    if b.hardness == INF:
        return 0.0
    if b.hardness == 0.0:
        return 1.0
    tool = TOOLS.get(held or "")
    speed = tool.speed if tool is not None and tool.kind == b.tool else 1.0
    return speed / b.hardness / (30.0 if can_harvest(block, held) else 100.0)


def ticks_to_break(block: int, held: Optional[str]) -> float:
    """Ticks of continuous attack needed to break ``block`` (``inf`` if unbreakable)."""
    rate = break_progress_per_tick(block, held)
    return math.inf if rate == 0.0 else math.ceil(1.0 / rate - 1e-9)
