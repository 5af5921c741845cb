"""Keeping the agent alive: eating when hungry, getting out of water or lava, digging out
of a block that fell on it."""

from __future__ import annotations

from typing import Optional

from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent.leaves import control
from minecraft.agent.leaves.context import Leaf
from minecraft.agent.leaves.items import hold
from minecraft.agent.leaves.percept import RADIUS, Cell, Percept
from minecraft.agent.leaves.travel import break_block


class Eat(Leaf):
    """Action: hold the best food and keep ``use`` down until the food level rises."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Eat", namespace=namespace)
        self._food = 0
        self._ticks = 0

    def initialise(self) -> None:
        """Remember the food level."""
        self._food = self.ctx.percept.food
        self._ticks = 0

    def update(self) -> Status:
        """Select food, then use it for up to 40 ticks."""
        p, cmd = self.ctx.percept, self.ctx.commands
        cmd.still()
        if p.food > self._food:
            return Status.SUCCESS
        food = max((f for f in B.FOOD if p.count(f)), key=lambda f: B.FOOD[f][0], default=None)
        if food is None:
            return Status.FAILURE
        if not hold(p, cmd, food):
            return Status.RUNNING
        cmd.use = True
        self._ticks += 1
        return Status.RUNNING if self._ticks < 40 else Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        """Let go of ``use``."""
        self.ctx.commands.use = False


class EscapeLiquid(Leaf):
    """Action: swim up and head for the nearest dry cell with ground under it."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Escape liquid", namespace=namespace)

    def update(self) -> Status:
        """Jump (swim) and steer to dry land."""
        p, cmd = self.ctx.percept, self.ctx.commands
        cmd.still()
        cmd.jump = True
        ids = p.ids
        best, best_d = None, 1e9
        for gy in range(1, 2 * RADIUS):
            for gz in range(1, 2 * RADIUS):
                for gx in range(1, 2 * RADIUS):
                    feet, head, under = ids[gy, gz, gx], ids[gy + 1, gz, gx], ids[gy - 1, gz, gx]
                    if B.SOLID[feet] or B.LIQUID[feet] or B.SOLID[head] or B.LIQUID[head]:
                        continue
                    if not B.SOLID[under]:
                        continue
                    d = (gx - RADIUS) ** 2 + 2 * (gy - RADIUS) ** 2 + (gz - RADIUS) ** 2
                    if d < best_d:
                        best, best_d = (gx, gy, gz), d
        if best is not None:
            control.steer(p, p.to_world(best), cmd)
            cmd.jump = True
        return Status.RUNNING


def buried_cell(p: Percept) -> Optional[Cell]:
    """The solid block the body is in (head first, then feet: a block that fell on the
    agent, gravel or sand), or None."""
    x, y, z = p.cell
    for cell in ((x, y + 1, z), (x, y, z)):
        b = p.block(cell)
        if b is not None and B.SOLID[b] and not B.LIQUID[b]:
            return cell
    return None


class Buried(Leaf):
    """SUCCESS when a solid block fills the agent's feet or head cell."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Inside a block?", namespace=namespace)

    def update(self) -> Status:
        """Look at the agent's two cells."""
        return Status.SUCCESS if buried_cell(self.ctx.percept) is not None else Status.FAILURE


class DigOut(Leaf):
    """Action: break the block the agent is in (the planner cannot start from a solid
    cell, and a body inside a block neither falls nor walks)."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Dig out", namespace=namespace)

    def update(self) -> Status:
        """Aim at the block and dig; SUCCESS once both cells are free."""
        ctx = self.ctx
        cell = buried_cell(ctx.percept)
        if cell is None:
            return Status.SUCCESS
        status = break_block(ctx.percept, cell, ctx.commands, ctx.memory)
        return Status.RUNNING if status == Status.FAILURE else status
