"""The travel sub-tree (paper, Fig. 1): re-plan with A* every tick from the grid
observation, then either break the next block in the way or step to the next cell::

    [o] Travel                      Selector, memory=False
        --> At destination?
        [-] Plan and act            Sequence, memory=False
            --> Plan path (A*)      writes ctx.plan_step
            [o] Next action         Selector, memory=False
                [-] Destroy         Sequence, memory=False
                    --> Next is destroy?
                    --> Break block
                --> Step to cell

The destination is ``ctx.goals`` (world feet cells), set by the leaf before the sub-tree.
"""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from minecraft import blocks as B
from minecraft.agent import astar
from minecraft.agent.leaves import control
from minecraft.agent.leaves.context import Commands, Leaf
from minecraft.agent.leaves.items import hold, tool_for
from minecraft.agent.leaves.percept import RADIUS, SIDE, Cell, Percept

STUCK_TICKS = 40
AIRTIME_TICKS = 12  # a jump's time in the air
AIMED_DEGS = 3.0  # aim error under which the crosshair is on the planned face


class AtDestination(Leaf):
    """SUCCESS when the feet cell is one of ``ctx.goals`` and the agent stands."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("At destination?", namespace=namespace)

    def update(self) -> Status:
        """Compare the feet cell with the goals."""
        p = self.ctx.percept
        return Status.SUCCESS if p.cell in self.ctx.goals and p.on_ground else Status.FAILURE


class PlanPath(Leaf):
    """A* from the agent's block to the goals inside the grid; SUCCESS with the next step
    in ``ctx.plan_step``, FAILURE when no goal is in view or no step makes progress.

    While airborne (mid-jump or falling) the previous step is kept: the feet cell of a
    body in the air is not a state of the planner's model. A slow client (commands held
    ``hold`` > 1 ticks) keeps it only for a jump's air time after it was planned: it sees
    the body in the air at the start of a decision far more often, and a step kept from
    before a fall (a block mined underfoot) would steer it forever (a held jump towards
    a cell far above lands it in the air at every decision).
    """

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Plan path (A*)", namespace=namespace)

    def update(self) -> Status:
        """Plan, or keep the step while in the air."""
        ctx = self.ctx
        p = ctx.percept
        fresh = (
            ctx.commands.hold == 1 or p.tick - ctx.memory.get("planned_tick", 0) <= AIRTIME_TICKS
        )
        if not p.on_ground and ctx.plan_step is not None and not p.in_liquid() and fresh:
            return Status.SUCCESS
        goals = [g for g in (p.to_grid(c) for c in ctx.goals) if _inside(g)]
        if not goals:
            ctx.plan_step = None
            ctx.memory["last_plan_failed"] = True
            return Status.FAILURE
        plan = ctx.planner(p.categories, (RADIUS, RADIUS, RADIUS), goals)
        ctx.plan_reached = plan.reached
        if not plan.steps:
            ctx.plan_step = None
            ctx.memory["last_plan_failed"] = True
            return Status.FAILURE
        step = plan.steps[0]
        ctx.plan_step = (step.kind, p.to_world(step.cell))
        ctx.memory["planned_tick"] = p.tick
        return Status.SUCCESS


def _inside(g: Cell) -> bool:
    return all(0 <= v < SIDE for v in g)


class NextIsDestroy(Leaf):
    """SUCCESS when the planned step breaks a block."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Next is destroy?", namespace=namespace)

    def update(self) -> Status:
        """Read ctx.plan_step."""
        step = self.ctx.plan_step
        return Status.SUCCESS if step is not None and step[0] == "destroy" else Status.FAILURE


def break_block(p: Percept, cell: Cell, cmd: Commands, memory: dict) -> Status:
    """Aim at ``cell`` and hold attack while the crosshair is on it.

    RUNNING while the block stands, SUCCESS once it is gone, FAILURE when it cannot be
    broken from here (out of reach, or something unsafe is in the way for too long).
    """
    block = p.block(cell)
    if block is None:
        return Status.FAILURE
    if not B.SOLID[block] or B.LIQUID[block]:
        cmd.attack = False
        return Status.SUCCESS
    cmd.move = cmd.strafe = 0.0
    cmd.jump = False
    if not hold(p, cmd, tool_for(p, block)):
        cmd.attack = False
        return Status.RUNNING
    err = control.aim(p, control.face_point(p, cell), cmd)
    if control.looking_at(p, cell) or (err < AIMED_DEGS and control.item_on(p, cell)):
        cmd.attack = True
        memory["blocked"] = 0
        return Status.RUNNING
    cmd.attack = False
    if err < AIMED_DEGS:
        # Aimed but something else is hit: break it if that is safe, else give up soon.
        los = p.los
        other = (los.get("blockX"), los.get("blockY"), los.get("blockZ"))
        if los.get("hitType") == "block" and los.get("inRange") and _safe_to_break(p, other):
            cmd.attack = True
            return Status.RUNNING
        memory["blocked"] = memory.get("blocked", 0) + 1
        if memory["blocked"] > 20:
            memory["blocked"] = 0
            return Status.FAILURE
    return Status.RUNNING


def _safe_to_break(p: Percept, cell: tuple) -> bool:
    if None in cell:
        return False
    c = (int(cell[0]), int(cell[1]), int(cell[2]))
    if c == (p.cell[0], p.cell[1] - 1, p.cell[2]):
        return False  # never the block we stand on, unplanned
    b = p.block(c)
    if b is None or not B.SOLID[b] or B.BLOCKS[b].hardness == float("inf"):
        return False
    for dx, dy, dz in astar.NEIGHBOURS6:
        n = p.block((c[0] + dx, c[1] + dy, c[2] + dz))
        if n is not None and B.LIQUID[n]:
            return False
    return True


class BreakBlock(Leaf):
    """Action: break the block of the planned destroy step."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Break block", namespace=namespace)

    def update(self) -> Status:
        """Aim and dig."""
        ctx = self.ctx
        assert ctx.plan_step is not None
        return break_block(ctx.percept, ctx.plan_step[1], ctx.commands, ctx.memory)


class StepTo(Leaf):
    """Action: steer to the planned cell (RUNNING; the plan is redone every tick). Jumps
    when stuck in the same cell for STUCK_TICKS ticks."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("Step to cell", namespace=namespace)

    def update(self) -> Status:
        """Walk towards the step's cell."""
        ctx = self.ctx
        p, cmd = ctx.percept, ctx.commands
        if ctx.plan_step is None:
            return Status.FAILURE
        cmd.attack = False
        cmd.turn = 0.0
        cmd.pitch = control.turn_rate(10.0 - p.pitch, cmd.hold)
        control.steer(p, ctx.plan_step[1], cmd)
        mem = ctx.memory
        if mem.get("stuck_cell") != p.cell:
            mem["stuck_cell"], mem["stuck_ticks"] = p.cell, 0
        mem["stuck_ticks"] = mem.get("stuck_ticks", 0) + 1
        if mem["stuck_ticks"] > STUCK_TICKS:
            cmd.jump = True
            mem["stuck_total"] = mem.get("stuck_total", 0) + 1
        return Status.RUNNING


def travel_subtree(namespace: str) -> py_trees.behaviour.Behaviour:
    """The travel sub-tree to ``ctx.goals`` (see the module docstring)."""
    destroy = py_trees.composites.Sequence(
        "Destroy",
        memory=False,
        children=[NextIsDestroy(namespace=namespace), BreakBlock(namespace=namespace)],
    )
    act = py_trees.composites.Selector(
        "Next action", memory=False, children=[destroy, StepTo(namespace=namespace)]
    )
    go = py_trees.composites.Sequence(
        "Plan and act", memory=False, children=[PlanPath(namespace=namespace), act]
    )
    return py_trees.composites.Selector(
        "Travel", memory=False, children=[AtDestination(namespace=namespace), go]
    )
