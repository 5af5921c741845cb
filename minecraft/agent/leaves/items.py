"""Inventory leaves and helpers: holding the right item (``hotbar.N``,
``swapInventoryItems``) and crafting or smelting (``craft <item>``).

Malmo's SimpleCraft smelts without a furnace GUI: it burns fuel whole items at a time
from the first inventory slot up, whatever the item (sticks, planks, the wooden pickaxe).
Before smelting, ``Craft`` swaps the fuel it means to burn (``FUEL_ORDER``) into the
first slot holding any fuel, so coal goes before the wood that later tools need."""

from __future__ import annotations

from typing import Optional

from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent.leaves.context import Commands, Leaf
from minecraft.agent.leaves.percept import Percept

PICKAXES = ("diamond_pickaxe", "iron_pickaxe", "stone_pickaxe", "wooden_pickaxe")
HOTBAR = 9
SWAP_SLOT = 8  # the hotbar slot items from the main inventory are swapped into
SMELTED = frozenset({"iron_ingot", "gold_ingot"})
"""Items ``craft`` makes by smelting (burning fuel)."""
FUEL_ORDER = ("coal", "planks", "log")
"""The fuel burnt first when smelting: never sticks or wooden tools while these last."""


def best_pickaxe(p: Percept, level: int = B.WOOD) -> Optional[str]:
    """The best pickaxe held in the inventory of at least harvest ``level``."""
    for name in PICKAXES:
        if p.count(name) and B.TOOLS[name].level >= level:
            return name
    return None


def tool_for(p: Percept, block: int) -> Optional[str]:
    """The item to hold to break ``block``: the best pickaxe for pickaxe blocks, else
    nothing (a bare hand spares the tools' durability)."""
    if B.BLOCKS[block].tool == "pickaxe":
        return best_pickaxe(p)
    return None


def hold(p: Percept, cmd: Commands, item: Optional[str]) -> bool:
    """Write the commands that put ``item`` (None: an empty hand) in the selected slot.

    Returns:
        True when it is already held.
    """
    held = p.held()
    if item is None:
        if held is None or held not in B.TOOLS:
            return True
        used = {i for idx in p.slots.values() for i in idx}
        free = [s for s in range(HOTBAR) if s not in used or not _tool_in(p, s)]
        if free:
            cmd.once.append(f"hotbar.{free[0] + 1} 1")
        return False
    if held == item:
        return True
    slots = p.slots.get(item, [])
    if not slots:
        return False
    slot = min(slots)
    if slot < HOTBAR:
        cmd.once.append(f"hotbar.{slot + 1} 1")
    else:
        cmd.once.append(f"swapInventoryItems {slot} {SWAP_SLOT}")
        cmd.once.append(f"hotbar.{SWAP_SLOT + 1} 1")
    return False


def fuel_swap(p: Percept) -> Optional[str]:
    """The ``swapInventoryItems`` command that puts the preferred fuel (``FUEL_ORDER``)
    in the first slot holding any fuel, or None when it is there already (or there is
    none of it)."""
    at = {s: item for item, idx in p.slots.items() for s in idx}
    fuel_slots = sorted(s for s, item in at.items() if item in B.FUEL)
    if not fuel_slots:
        return None
    first = fuel_slots[0]
    for item in FUEL_ORDER:
        slots = p.slots.get(item)
        if slots:
            if at[first] == item:
                return None
            return f"swapInventoryItems {first} {min(slots)}"
    return None


def _tool_in(p: Percept, slot: int) -> bool:
    return any(slot in idx and item in B.TOOLS for item, idx in p.slots.items())


class Craft(Leaf):
    """Action: ``craft <item>`` once; SUCCESS when the inventory shows more of it,
    FAILURE if it did not after a few ticks (a missing ingredient, table or fuel).
    Before smelting, the preferred fuel is swapped into the first fuel slot
    (``fuel_swap``, at most ``SWAPS`` tries)."""

    SWAPS = 3

    def __init__(self, item: str, *, namespace: str) -> None:
        """Args: item: the Minecraft name to craft or smelt; namespace: blackboard."""
        super().__init__(f"Craft {item}", namespace=namespace)
        self.item = item
        self._before = 0
        self._ticks = 0
        self._swaps = 0

    def initialise(self) -> None:
        """Remember the count before crafting."""
        self._before = self.ctx.percept.count(self.item)
        self._ticks = self._swaps = 0

    def update(self) -> Status:
        """Arrange the fuel, send the craft command, then wait for the inventory to change."""
        p, cmd = self.ctx.percept, self.ctx.commands
        if self._ticks == 0 and self.item in SMELTED and self._swaps < self.SWAPS:
            swap = fuel_swap(p)
            if swap is not None:
                cmd.still()
                cmd.once.append(swap)
                self._swaps += 1
                return Status.RUNNING
        if self._ticks == 0:
            cmd.still()
            cmd.once.append(f"craft {self.item}")
            self._ticks = 1
            return Status.RUNNING
        if p.count(self.item) > self._before:
            return Status.SUCCESS
        self._ticks += 1
        return Status.RUNNING if self._ticks < 4 else Status.FAILURE
