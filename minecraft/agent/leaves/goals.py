"""Where to go: the block to mine and the cells to stand on to reach it, exploration on
the surface or through the rock, safe descent, and picking up dropped items. These leaves
only write ``ctx.goals`` / ``ctx.target``; the travel sub-tree does the walking."""

from __future__ import annotations

import random
from typing import Optional

from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent import astar
from minecraft.agent.leaves.context import Leaf
from minecraft.agent.leaves.percept import RADIUS, Cell, Percept
from minecraft.agent.leaves.travel import break_block

PICKUP_TICKS = 20  # a drop can be picked up 10 ticks after it falls
TARGET_BUDGET = 600  # ticks spent on one target before it is given up
HEADINGS: tuple[tuple[int, int], ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))


def stand_cells(p: Percept, t: Cell) -> list[Cell]:
    """Feet cells from which block ``t`` is a neighbour the agent can break."""
    x, y, z = t
    out = [(x, y - 2, z)]  # t is just above the head
    below = p.block((x, y - 1, z))
    if below is not None and B.SOLID[below]:
        out.append((x, y + 1, z))  # standing on t: breaking it drops us 1 block
    for dx, dz in astar.HORIZONTAL:
        out.append((x - dx, y, z - dz))
        out.append((x - dx, y - 1, z - dz))
    return out


def touches_liquid(p: Percept, t: Cell) -> bool:
    """A liquid is next to ``t`` (breaking it would let the liquid in)."""
    for dx, dy, dz in astar.NEIGHBOURS6:
        b = p.block((t[0] + dx, t[1] + dy, t[2] + dz))
        if b is not None and B.LIQUID[b]:
            return True
    return False


class ChooseBlock(Leaf):
    """SUCCESS with ``ctx.target`` the nearest visible block of ``names`` (not touching
    a liquid, not given up before) and ``ctx.goals`` the cells to mine it from; FAILURE
    when there is none in the grid."""

    def __init__(self, names: tuple[str, ...], *, namespace: str, max_y: int = 255) -> None:
        """Args: names: block names; namespace: blackboard; max_y: ignore blocks above."""
        super().__init__(f"Choose {'/'.join(names)}", namespace=namespace)
        self.names = names
        self.max_y = max_y

    def update(self) -> Status:
        """Pick (or keep) a target."""
        ctx = self.ctx
        p, mem = ctx.percept, ctx.memory
        given_up: set = mem.setdefault("given_up", set())
        cur = ctx.target
        if cur is not None and p.name(cur) in self.names and cur not in given_up:
            spent = p.tick - mem.get("target_since", p.tick)
            if spent <= TARGET_BUDGET:
                ctx.goals = frozenset(stand_cells(p, cur))
                return Status.SUCCESS
            given_up.add(cur)
        for t in p.find(self.names):
            if t in given_up or t[1] > self.max_y or touches_liquid(p, t):
                continue
            ctx.target = t
            mem["target_since"] = p.tick
            ctx.goals = frozenset(stand_cells(p, t))
            return Status.SUCCESS
        ctx.target = None
        return Status.FAILURE


class MineTarget(Leaf):
    """Action: break ``ctx.target`` (aiming, the right tool, holding attack), then wait
    up to PICKUP_TICKS for its drop to reach the inventory; SUCCESS only after that, so
    a following craft sees the item."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Mine target", namespace=namespace)
        self._drop: Optional[str] = None
        self._before = 0
        self._since = 0

    def initialise(self) -> None:
        """Note what the target drops and how many of it are held."""
        ctx = self.ctx
        self._drop, self._since = None, 0
        if ctx.target is not None:
            b = ctx.percept.block(ctx.target)
            if b is not None and B.BLOCKS[b].drop:
                self._drop = B.BLOCKS[b].drop
                self._before = ctx.percept.count(self._drop)

    def update(self) -> Status:
        """Dig until the target is gone, then wait for the pick-up."""
        ctx = self.ctx
        p = ctx.percept
        if self._since:
            if self._drop is None or p.count(self._drop) > self._before:
                return Status.SUCCESS
            return Status.RUNNING if p.tick - self._since < PICKUP_TICKS else Status.SUCCESS
        if ctx.target is None:
            return Status.FAILURE
        status = break_block(p, ctx.target, ctx.commands, ctx.memory)
        if status == Status.FAILURE:
            ctx.memory.setdefault("given_up", set()).add(ctx.target)
        if status == Status.SUCCESS:
            self._since = p.tick
            return Status.RUNNING
        return status


def heading_goals(cell: Cell, heading: int, *, level: bool) -> frozenset[Cell]:
    """Feet cells 6-7 blocks from ``cell`` along ``HEADINGS[heading]``, 5 wide: at the
    same height (``level``) or within 3 of it."""
    dx, dz = HEADINGS[heading]
    x, y, z = cell
    dys = (0,) if level else (-3, -2, -1, 0, 1, 2, 3)
    goals = set()
    for reach in (RADIUS - 1, RADIUS):
        for side in range(-2, 3):
            for dy in dys:
                goals.add((x + dx * reach + dz * side, y + dy, z + dz * reach + dx * side))
    return frozenset(goals)


class Elsewhere(Leaf):
    """SUCCESS after setting ``ctx.goals`` to cells 6-7 blocks away at the current height
    along a heading drawn once per watchdog firing (``ctx.memory[key]`` holds the
    firing's tick and the goals): the travel sub-tree then reaches them once."""

    def __init__(self, *, namespace: str, key: str, seed: int = 0) -> None:
        """Args: namespace: blackboard; key: the memory key of the firing (its
        ``tick``); seed: for the headings."""
        super().__init__("Go elsewhere", namespace=namespace)
        self.key = key
        self.rng = random.Random(seed)

    def update(self) -> Status:
        """Draw the goals for a new firing, keep them otherwise."""
        ctx = self.ctx
        fired = ctx.memory.get(self.key)
        tick = fired.tick if fired is not None else ctx.percept.tick
        state = ctx.memory.get("elsewhere")
        if state is None or state[0] != tick:
            goals = heading_goals(ctx.percept.cell, self.rng.randrange(4), level=True)
            state = (tick, goals)
            ctx.memory["elsewhere"] = state
        ctx.goals = state[1]
        return Status.SUCCESS


class Explore(Leaf):
    """SUCCESS after setting ``ctx.goals`` to cells 6-7 blocks away along a heading:
    on the surface (``level`` False: any height within 3) or in a tunnel at the current
    height (``level`` True). The heading turns when the goal is reached, cannot be
    planned to, or is not reached in time."""

    def __init__(self, *, namespace: str, level: bool, seed: int = 0) -> None:
        """Args: namespace: blackboard; level: keep the height (tunnelling); seed: for
        the first heading."""
        super().__init__("Explore (tunnel)" if level else "Explore (surface)", namespace=namespace)
        self.level = level
        self.rng = random.Random(seed)

    def update(self) -> Status:
        """Keep or renew the exploration goal."""
        ctx = self.ctx
        p, mem = ctx.percept, ctx.memory
        key = "explore_tunnel" if self.level else "explore_surface"
        state = mem.get(key)
        renew = state is None or p.cell in state["goals"] or p.tick - state["since"] > 300
        if state is not None and not renew and mem.get("last_plan_failed"):
            renew = True
        if renew:
            heading = self.rng.randrange(4) if state is None else state["heading"]
            if state is not None and (p.tick - state["since"] > 300 or mem.get("last_plan_failed")):
                heading = (heading + self.rng.choice((1, 3))) % 4
            goals = heading_goals(p.cell, heading, level=self.level)
            state = {"heading": heading, "goals": goals, "since": p.tick}
            mem[key] = state
            mem["last_plan_failed"] = False
        assert state is not None  # renewed above when there was none
        ctx.goals = state["goals"]
        return Status.SUCCESS


class Descend(Leaf):
    """SUCCESS after setting ``ctx.goals`` to cells up to 6 blocks lower (not below
    ``y``) in a 5×5 column around the agent; A* then digs down the safe way (never into a
    fall longer than 3 blocks or next to a liquid)."""

    def __init__(self, y: int, *, namespace: str) -> None:
        """Args: y: the height to reach; namespace: blackboard."""
        super().__init__(f"Descend to y={y}", namespace=namespace)
        self.y = y

    def update(self) -> Status:
        """Set the goals one stretch down."""
        ctx = self.ctx
        p = ctx.percept
        x, y, z = p.cell
        state = ctx.memory.get("descend")
        if state is None or p.cell[1] <= state["y"] or p.tick - state["since"] > 400:
            shift = 0 if state is None else state.get("shift", 0) + 1
            ty = max(self.y, y - 6)
            sx, sz = (
                HEADINGS[shift % 4]
                if state is not None and p.tick - state["since"] > 400
                else (0, 0)
            )
            goals = frozenset(
                (x + sx * 3 + dx, ty, z + sz * 3 + dz) for dx in range(-2, 3) for dz in range(-2, 3)
            )
            state = {"y": ty, "goals": goals, "since": p.tick, "shift": shift}
            ctx.memory["descend"] = state
        ctx.goals = state["goals"]
        return Status.SUCCESS


class Ascend(Leaf):
    """SUCCESS after setting ``ctx.goals`` to cells ``STRETCH`` blocks higher in a 5×5
    column around the agent; A* digs a staircase up to them (the way back to the
    surface, where the trees are)."""

    STRETCH = 4

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Ascend", namespace=namespace)

    def update(self) -> Status:
        """Set the goals one stretch up (renewed once reached or after 400 ticks)."""
        ctx = self.ctx
        p = ctx.percept
        x, y, z = p.cell
        state = ctx.memory.get("ascend")
        if state is None or y >= state["y"] or p.tick - state["since"] > 400:
            ty = y + self.STRETCH
            goals = frozenset((x + dx, ty, z + dz) for dx in range(-2, 3) for dz in range(-2, 3))
            state = {"y": ty, "goals": goals, "since": p.tick}
            ctx.memory["ascend"] = state
        ctx.goals = state["goals"]
        return Status.SUCCESS


class ChooseDrop(Leaf):
    """SUCCESS with ``ctx.goals`` the cell of the nearest dropped item worth having
    within 4 blocks; FAILURE when there is none (or it was chased too long). Items
    whose uid is in ``ctx.memory["skipped_drops"]`` (left by a learned correction) are
    not chased."""

    def __init__(self, names: tuple[str, ...], *, namespace: str) -> None:
        """Args: names: item names to pick up; namespace: blackboard."""
        super().__init__("Drop nearby?", namespace=namespace)
        self.names = frozenset(names)

    def update(self) -> Status:
        """Look for items in the entity list."""
        ctx = self.ctx
        p, mem = ctx.percept, ctx.memory
        chased: dict = mem.setdefault("chased", {})
        left: set = mem.get("skipped_drops", set())
        best = None
        for it in p.items:
            if it.name not in self.names or it.uid in left:
                continue
            d = abs(it.x - p.x) + abs(it.y - p.y) + abs(it.z - p.z)
            first = chased.setdefault(it.uid, p.tick)
            if d > 4.0 or p.tick - first > 100:
                continue
            if best is None or d < best[0]:
                best = (d, it)
        if best is None:
            return Status.FAILURE
        it = best[1]
        cell = (int(it.x // 1), int((it.y + 0.01) // 1), int(it.z // 1))
        ctx.goals = frozenset({cell, (cell[0], cell[1] - 1, cell[2])})
        return Status.SUCCESS
