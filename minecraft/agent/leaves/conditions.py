"""Condition leaves: checks on the percept that return SUCCESS or FAILURE."""

from __future__ import annotations

from collections.abc import Mapping

from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent.leaves.context import Leaf
from minecraft.agent.leaves.percept import RADIUS


class HasItems(Leaf):
    """SUCCESS when the inventory holds at least the given counts (any one of
    ``alternatives`` counts as the item itself: a better tool satisfies a worse one)."""

    def __init__(
        self,
        need: Mapping[str, int],
        *,
        namespace: str,
        alternatives: tuple[str, ...] = (),
    ) -> None:
        """Args: need: item -> count; namespace: blackboard; alternatives: items that
        satisfy the whole condition on their own."""
        label = ", ".join(f"{n} {k}" for k, n in need.items())
        super().__init__(f"Has {label}?", namespace=namespace)
        self.need = dict(need)
        self.alternatives = alternatives

    def update(self) -> Status:
        """Compare the inventory with the need."""
        p = self.ctx.percept
        if any(p.count(a) for a in self.alternatives):
            return Status.SUCCESS
        ok = all(p.count(k) >= n for k, n in self.need.items())
        return Status.SUCCESS if ok else Status.FAILURE


class Hungry(Leaf):
    """SUCCESS when food is at or below ``threshold`` and there is something to eat."""

    def __init__(self, *, namespace: str, threshold: int = 14) -> None:
        """Args: namespace: blackboard; threshold: food level (of 20) that counts."""
        super().__init__("Hungry and have food?", namespace=namespace)
        self.threshold = threshold

    def update(self) -> Status:
        """Check food and the inventory."""
        p = self.ctx.percept
        has_food = any(p.count(f) for f in B.FOOD)
        return Status.SUCCESS if p.food <= self.threshold and has_food else Status.FAILURE


class InLiquid(Leaf):
    """SUCCESS when the agent's feet or head are in water or lava."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("In water or lava?", namespace=namespace)

    def update(self) -> Status:
        """Check the agent's two cells in the grid."""
        return Status.SUCCESS if self.ctx.percept.in_liquid() else Status.FAILURE


class AboveDepth(Leaf):
    """SUCCESS when the feet are above world height ``y``."""

    def __init__(self, y: int, *, namespace: str) -> None:
        """Args: y: the height; namespace: blackboard."""
        super().__init__(f"Above y={y}?", namespace=namespace)
        self.y = y

    def update(self) -> Status:
        """Compare the feet cell's height."""
        return Status.SUCCESS if self.ctx.percept.cell[1] > self.y else Status.FAILURE


class Underground(Leaf):
    """SUCCESS when rock, ore or earth lies above the head within the grid (trees grow
    on the surface, under the open sky; logs and leaves above do not count)."""

    OPEN = frozenset({"log", "log2", "leaves", "leaves2"})

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Underground?", namespace=namespace)

    def update(self) -> Status:
        """Look up the agent's column."""
        p = self.ctx.percept
        x, y, z = p.cell
        for dy in range(2, RADIUS + 1):
            b = p.block((x, y + dy, z))
            if b is not None and B.SOLID[b] and B.NAMES[b] not in self.OPEN:
                return Status.SUCCESS
        return Status.FAILURE


class WoodStock(Leaf):
    """SUCCESS when the wood held (in planks: 4 per log, 1 per plank, 1/2 per stick)
    covers what the rest of the quest needs plus ``margin`` planks: the table, the
    wooden pickaxe, sticks for the later pickaxes and fuel for smelting. Trees grow on
    the surface only, so all the wood is gathered before going down; once the stone
    pickaxe is made (the agent is underground) the wood is never asked for again."""

    def __init__(self, *, namespace: str, margin: int = 4) -> None:
        """Args: namespace: blackboard; margin: spare planks."""
        super().__init__("Enough wood?", namespace=namespace)
        self.margin = margin

    def update(self) -> Status:
        """Count wood against the remaining needs."""
        p = self.ctx.percept
        if p.count("iron_pickaxe") or p.count("stone_pickaxe"):
            # Past the surface: no more trees down here; fuel then comes from coal.
            return Status.SUCCESS
        have = 4 * p.count("log") + p.count("planks") + p.count("stick") / 2
        need = 0.0 if p.count("crafting_table") else 4.0
        if not any(p.count(t) for t in ("wooden_pickaxe", "stone_pickaxe", "iron_pickaxe")):
            need += 3 + 1
        if not p.count("stone_pickaxe"):
            need += 1
        need += 1  # sticks for the iron pickaxe
        if p.count("iron_ingot") < 3 and not p.count("coal"):
            need += 2  # fuel: 1.5 smelts per plank
        return Status.SUCCESS if have >= need + self.margin else Status.FAILURE
