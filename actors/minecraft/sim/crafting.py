"""Crafting and smelting for ``SimpleCraftCommands`` (``craft <item>``), with Minecraft's
quantities for the obtain-diamond tech tree.

Malmo's own SimpleCraft ignores where the agent stands; graft is stricter and closer to
the game: 3×3 recipes need a crafting table (in the inventory or placed within reach)
and smelting needs a furnace (likewise) plus fuel. Fuel is burnt whole items at a time
and its unused part carries over (a coal smelts 8 items).
"""

from __future__ import annotations

from dataclasses import dataclass

from actors.minecraft.blocks import FUEL
from actors.minecraft.sim.inventory import Inventory


@dataclass(frozen=True)
class Recipe:
    """A shapeless view of a Minecraft recipe.

    Attributes:
        output: item produced.
        count: how many are produced per craft.
        inputs: item -> number consumed.
        needs_table: True for 3×3 recipes (crafting table required).
    """

    output: str
    count: int
    inputs: tuple[tuple[str, int], ...]
    needs_table: bool


def _r(output: str, count: int, table: bool, **inputs: int) -> Recipe:
    return Recipe(output, count, tuple(inputs.items()), table)


RECIPES: dict[str, Recipe] = {
    r.output: r
    for r in (
        _r("planks", 4, False, log=1),
        _r("stick", 4, False, planks=2),
        _r("crafting_table", 1, False, planks=4),
        _r("torch", 4, False, coal=1, stick=1),
        _r("wooden_pickaxe", 1, True, planks=3, stick=2),
        _r("stone_pickaxe", 1, True, cobblestone=3, stick=2),
        _r("iron_pickaxe", 1, True, iron_ingot=3, stick=2),
        _r("diamond_pickaxe", 1, True, diamond=3, stick=2),
        _r("wooden_axe", 1, True, planks=3, stick=2),
        _r("stone_axe", 1, True, cobblestone=3, stick=2),
        _r("iron_axe", 1, True, iron_ingot=3, stick=2),
        _r("wooden_shovel", 1, True, planks=1, stick=2),
        _r("stone_shovel", 1, True, cobblestone=1, stick=2),
        _r("iron_shovel", 1, True, iron_ingot=1, stick=2),
        _r("wooden_sword", 1, True, planks=2, stick=1),
        _r("stone_sword", 1, True, cobblestone=2, stick=1),
        _r("iron_sword", 1, True, iron_ingot=2, stick=1),
        _r("furnace", 1, True, cobblestone=8),
        _r("bread", 1, True, wheat=3),
    )
}

# Smelting: output -> input (one input item gives one output item).
SMELTING: dict[str, str] = {
    "iron_ingot": "iron_ore",
    "gold_ingot": "gold_ore",
    "cooked_porkchop": "porkchop",
    "cooked_beef": "beef",
    "glass": "sand",
    "stone": "cobblestone",
    "coal": "log",  # charcoal (coal variant 1 in 1.11)
}

# Fuel preference: cheapest useful fuel first.
_FUEL_ORDER = ("coal", "planks", "log", "stick", "wooden_shovel", "wooden_sword")


@dataclass
class CraftState:
    """Per-player crafting state: fuel already paid for but not yet used."""

    fuel_credit: float = 0.0


def craft(
    inv: Inventory, state: CraftState, item: str, *, table_near: bool, furnace_near: bool
) -> tuple[bool, str]:
    """Craft or smelt one batch of ``item``.

    Args:
        inv: the inventory, changed in place on success.
        state: fuel credit carried between smelts.
        item: the requested output name.
        table_near: a crafting table is placed within reach (one in the inventory counts
            too; checked here).
        furnace_near: a furnace is placed within reach (idem).

    Returns:
        (success, reason): reason says what was missing when success is False.
    """
    recipe = RECIPES.get(item)
    if recipe is not None:
        if recipe.needs_table and not (table_near or inv.count("crafting_table") > 0):
            return False, f"{item} needs a crafting table"
        for name, n in recipe.inputs:
            if inv.count(name) < n:
                return False, f"{item} needs {n} {name}"
        if inv.room_for(item) < recipe.count:
            return False, "inventory full"
        for name, n in recipe.inputs:
            inv.remove(name, n)
        inv.add(item, recipe.count)
        return True, ""
    source = SMELTING.get(item)
    if source is None:
        return False, f"no recipe for {item}"
    if not (furnace_near or inv.count("furnace") > 0):
        return False, f"smelting {item} needs a furnace"
    if inv.count(source) < 1:
        return False, f"{item} needs 1 {source}"
    if inv.room_for(item) < 1:
        return False, "inventory full"
    while state.fuel_credit < 1.0 - 1e-9:
        # Never burn the very item being smelted.
        fuel = next((f for f in _FUEL_ORDER if f != source and inv.count(f) > 0), None)
        if fuel is None:
            return False, f"smelting {item} needs fuel"
        inv.remove(fuel, 1)
        state.fuel_credit += FUEL[fuel]
    inv.remove(source, 1)
    state.fuel_credit -= 1.0
    state.fuel_credit = max(state.fuel_credit, 0.0)
    inv.add(item, 1)
    return True, ""
