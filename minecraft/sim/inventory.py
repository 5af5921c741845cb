"""The player's inventory: 41 slots as in Minecraft (0-8 hotbar, 9-35 main, 36-40 armour
and off-hand), stacks of up to 64 (tools 1, with durability)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from minecraft.blocks import TOOLS, max_stack

N_SLOTS = 41
N_STORAGE = 36  # slots that pick-ups and crafting fill (hotbar first)


@dataclass
class Stack:
    """Items in one slot.

    Attributes:
        item: Minecraft item name.
        count: number of items (1..64).
        uses: durability left, for tools (0 for other items).
    """

    item: str
    count: int
    uses: int = 0


class Inventory:
    """Slots, the selected hotbar slot, and counting helpers."""

    def __init__(self) -> None:
        self.slots: list[Optional[Stack]] = [None] * N_SLOTS
        self.selected = 0

    def held(self) -> Optional[str]:
        """Name of the item in the selected hotbar slot, or None."""
        s = self.slots[self.selected]
        return s.item if s is not None else None

    def count(self, item: str) -> int:
        """Total number of ``item`` across all slots."""
        return sum(s.count for s in self.slots if s is not None and s.item == item)

    def add(self, item: str, count: int) -> int:
        """Add items, filling existing stacks then empty slots (hotbar first).

        Returns:
            How many items did not fit.
        """
        limit = max_stack(item)
        for s in self.slots[:N_STORAGE]:
            if count == 0:
                return 0
            if s is not None and s.item == item and s.count < limit:
                n = min(limit - s.count, count)
                s.count += n
                count -= n
        for i in range(N_STORAGE):
            if count == 0:
                return 0
            if self.slots[i] is None:
                n = min(limit, count)
                tool = TOOLS.get(item)
                self.slots[i] = Stack(item, n, tool.durability if tool else 0)
                count -= n
        return count

    def room_for(self, item: str) -> int:
        """How many ``item`` could be added."""
        limit = max_stack(item)
        room = 0
        for s in self.slots[:N_STORAGE]:
            if s is None:
                room += limit
            elif s.item == item:
                room += limit - s.count
        return room

    def remove(self, item: str, count: int) -> bool:
        """Remove ``count`` of ``item`` (selected slot last); False, unchanged, if short."""
        if self.count(item) < count:
            return False
        order = [i for i in range(N_SLOTS) if i != self.selected] + [self.selected]
        for i in order:
            s = self.slots[i]
            if count == 0:
                break
            if s is not None and s.item == item:
                n = min(s.count, count)
                s.count -= n
                count -= n
                if s.count == 0:
                    self.slots[i] = None
        return True

    def wear_held(self, amount: int = 1) -> None:
        """Use up durability of the held tool; it breaks (disappears) at zero."""
        s = self.slots[self.selected]
        if s is None or s.item not in TOOLS:
            return
        s.uses -= amount
        if s.uses <= 0:
            self.slots[self.selected] = None

    def swap(self, a: int, b: int) -> None:
        """Swap two slots (``swapInventoryItems a b``); out-of-range indices are ignored."""
        if 0 <= a < N_SLOTS and 0 <= b < N_SLOTS:
            self.slots[a], self.slots[b] = self.slots[b], self.slots[a]

    def combine(self, a: int, b: int) -> None:
        """Move as much of slot ``b`` into slot ``a`` as fits (``combineInventoryItems a b``)."""
        if not (0 <= a < N_SLOTS and 0 <= b < N_SLOTS) or a == b:
            return
        sa, sb = self.slots[a], self.slots[b]
        if sb is None:
            return
        if sa is None:
            self.slots[a], self.slots[b] = sb, None
            return
        if sa.item != sb.item:
            return
        n = min(max_stack(sa.item) - sa.count, sb.count)
        sa.count += n
        sb.count -= n
        if sb.count == 0:
            self.slots[b] = None

    def remove_selected_one(self) -> None:
        """Use up one item of the selected stack (eating, placing)."""
        s = self.slots[self.selected]
        if s is not None:
            s.count -= 1
            if s.count <= 0:
                self.slots[self.selected] = None

    def take_selected(self, count: Optional[int] = None) -> Optional[Stack]:
        """Remove and return (part of) the selected stack."""
        s = self.slots[self.selected]
        if s is None:
            return None
        n = s.count if count is None else min(count, s.count)
        s.count -= n
        if s.count == 0:
            self.slots[self.selected] = None
        return Stack(s.item, n, s.uses)
