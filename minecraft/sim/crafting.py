"""Crafting and smelting for ``SimpleCraftCommands`` (``craft <item>``), with Minecraft's
quantities for the obtain-diamond tech tree.

Malmo's own SimpleCraft ignores where the agent stands; graft is stricter and closer to
the game: 3×3 recipes need a crafting table (in the inventory or placed within reach)
and smelting needs a furnace (likewise) plus fuel. Fuel is burnt whole items at a time
and its unused part carries over (a coal smelts 8 items).
"""

from __future__ import annotations

from dataclasses import dataclass

from minecraft.blocks import FUEL
from minecraft.sim.inventory import N_STORAGE, Inventory


@dataclass(frozen=True)
class Recipe:
    """A shapeless view of a Minecraft recipe.

    Attributes:
        output: item produced.
        count: how many are produced per craft.
        inputs: item -> number consumed.
        needs_table: a 3×3 recipe (in Minecraft it needs a crafting table; SimpleCraft
            does not ask for one).
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


@dataclass
class CraftState:
    """Per-player crafting state: fuel already burnt but not yet used (in smelts)."""

    fuel_credit: float = 0.0


def craft(inv: Inventory, state: CraftState, item: str) -> tuple[bool, str, list[tuple[str, int]]]:
    """Craft or smelt one batch of ``item``, as Malmo's SimpleCraft does: wherever the
    player stands, no crafting table or furnace needed.

    Smelting needs one smelt's worth of fuel across the inventory (a coal smelts 8, a
    plank 1.5); fuel is burnt whole items at a time from the first inventory slot up,
    whatever the item (sticks and wooden tools burn too), and the unused part carries
    over to the next smelt.

    Args:
        inv: the inventory, changed in place on success.
        state: fuel credit carried between smelts.
        item: the requested output name.

    Returns:
        (success, reason, ingredients used): reason says what was missing on failure.
    """
    recipe = RECIPES.get(item)
    if recipe is not None:
        for name, n in recipe.inputs:
            if inv.count(name) < n:
                return False, f"{item} needs {n} {name}", []
        if inv.room_for(item) < recipe.count:
            return False, "inventory full", []
        for name, n in recipe.inputs:
            inv.remove(name, n)
        inv.add(item, recipe.count)
        return True, "", list(recipe.inputs)
    source = SMELTING.get(item)
    if source is None:
        return False, f"no recipe for {item}", []
    if inv.count(source) < 1:
        return False, f"{item} needs 1 {source}", []
    storage = inv.slots[:N_STORAGE]
    fuel = state.fuel_credit + sum(s.count * FUEL.get(s.item, 0.0) for s in storage if s)
    if fuel < 1.0 - 1e-9:
        return False, f"smelting {item} needs fuel", []
    if inv.room_for(item) < 1:
        return False, "inventory full", []
    inv.remove(source, 1)
    state.fuel_credit -= 1.0
    i = 0
    while state.fuel_credit < -1e-9 and i < N_STORAGE:
        s = inv.slots[i]
        if s is None or s.item not in FUEL:
            i += 1
            continue
        state.fuel_credit += FUEL[s.item]
        s.count -= 1
        if s.count == 0:
            inv.slots[i] = None
            i += 1
    inv.add(item, 1)
    return True, "", [(source, 1)]
