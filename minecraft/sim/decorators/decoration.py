"""What a world generator adds to a mission: the blocks it draws (as drawing operations,
run where the generator stands among the mission's decorators), the start it moves every
agent to, and the quit producers and subgoal observations it gives every agent."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from minecraft.malmo.mission import DrawOp, Subgoal
from minecraft.malmo.mission_rules import PositionQuit


@dataclass(frozen=True)
class Decoration:
    """A generator's output for one mission and seed.

    Attributes:
        ops: drawing operations, in order.
        start: where every agent starts (feet), or None to keep the placements.
        quits: AgentQuitFromReachingPosition markers added to every agent.
        subgoals: ObservationFromSubgoalPositionList points added to every agent.
    """

    ops: tuple[DrawOp, ...] = ()
    start: Optional[tuple[float, float, float]] = None
    quits: tuple[PositionQuit, ...] = ()
    subgoals: tuple[Subgoal, ...] = ()


def block(x: int, y: int, z: int, name: str) -> DrawOp:
    """One block."""
    return DrawOp("block", (x, y, z), name)


def cuboid(lo: tuple[int, int, int], hi: tuple[int, int, int], name: str) -> DrawOp:
    """The blocks from ``lo`` to ``hi``, both included."""
    return DrawOp("cuboid", (*lo, *hi), name)


def seed_or(text: Optional[str], world_seed: int) -> int:
    """A generator's seed as written, or the world's for ``random``, nothing, or text
    that is no number (Java's ``System.currentTimeMillis()`` or ``new Random()``)."""
    try:
        return int((text or "").strip())
    except ValueError:
        return world_seed
