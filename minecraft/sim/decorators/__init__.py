"""Malmo's world generators beyond drawing: ``MazeDecorator`` (``maze``),
``ClassroomDecorator`` (``classroom``, drawn by ``classroom_draw``) and
``BuildBattleDecorator`` with ``RewardForStructureCopying`` (``build_battle``).

``expand`` turns a mission's maze and classroom into what they add (``Decoration``):
their blocks join the mission's drawing where the decorator stands among the others,
every agent starts where the generator says, and its quit and subgoal producers join
every agent's. The build battle draws nothing; it scores the world as it changes.
"""

from __future__ import annotations

import dataclasses

from minecraft.malmo.mission import Mission
from minecraft.sim.decorators import classroom, maze
from minecraft.sim.decorators.classroom_draw import PALETTES
from minecraft.sim.decorators.decoration import Decoration

MAX_MAZE_BLOCKS = 512  # a maze wider or longer than this (cells × scale) is refused


def expand(mission: Mission, seed: int) -> Mission:
    """The mission with its maze and classroom turned into drawing, start, quits and
    subgoals (the same mission when it has neither; expanding twice changes nothing).

    Args:
        mission: the parsed mission (one agent's part of it).
        seed: the world's seed: it stands in for a generator's ``random`` seed.

    Raises:
        classroom.ClassroomError: the classroom cannot be built (as in Java).
    """
    parts: list[tuple[int, Decoration]] = []
    if mission.maze is not None:
        parts.append((mission.maze.at, maze.build(mission.maze, world_seed=seed)))
    if mission.classroom is not None:
        parts.append((mission.classroom.at, classroom.build(mission.classroom, world_seed=seed)))
    if not parts:
        return mission
    drawing = list(mission.drawing)
    placement, rules, subgoals = mission.placement, mission.rules, mission.subgoals
    for at, deco in sorted(parts, key=lambda p: -p[0]):  # later positions first
        drawing[at:at] = deco.ops
        if deco.start is not None:
            yaw, pitch = placement[3:] if placement is not None else (0.0, 0.0)
            placement = (*deco.start, yaw, pitch)
        rules = dataclasses.replace(rules, quit_positions=rules.quit_positions + deco.quits)
        subgoals += deco.subgoals
    return dataclasses.replace(
        mission, maze=None, classroom=None, drawing=tuple(drawing), placement=placement,
        rules=rules, subgoals=subgoals,
    )  # fmt: skip


def block_types(mission: Mission) -> set[str]:
    """Every block type the mission's generators may draw (for the support check)."""
    out: set[str] = set()
    m = mission.maze
    if m is not None:
        for b in (m.start, m.end, m.path, m.floor, m.gap, m.optimal_path, m.subgoal,
                  m.waypoint_block):  # fmt: skip
            if b is not None:
                out.update(b.types or ("air",))
    if mission.classroom is not None:
        names = PALETTES.values() if mission.classroom.palette == "random" else [
            PALETTES.get(mission.classroom.palette, PALETTES["dungeon"])]  # fmt: skip
        for pal in names:
            out.update(pal)
    bb = mission.build_battle
    if bb is not None:
        out.update(t for t in (bb.correct, bb.incorrect) if t)
    return out


def footprint(mission: Mission) -> list[tuple[float, float, float]]:
    """Corners of what the generators build (the world must contain them).

    Raises:
        ValueError: a maze too large to build.
    """
    pts: list[tuple[float, float, float]] = []
    m = mission.maze
    if m is not None:
        if (
            max(m.width * m.scale, m.length * m.scale) > MAX_MAZE_BLOCKS
            or min(m.width, m.length, m.scale) < 1
        ):
            raise ValueError(
                f"<MazeDecorator> of {m.width} x {m.length} cells at scale {m.scale}: the "
                f"simulator builds mazes of 1 to {MAX_MAZE_BLOCKS} blocks a side"
            )
        x, y, z = m.origin
        top = y + max(b.height + b.height_variance for b in (m.start, m.end, m.path, m.gap))
        pts += [(x, y, z), (x + m.width * m.scale - 1, top, z + m.length * m.scale - 1)]
    c = mission.classroom
    if c is not None:
        w, h, ln = c.size if c.size[0] else (60, 40, 60)  # complexity: up to ~40 wide
        x, y, z = classroom.ORIGIN
        pts += [(x - 2, y - 3, z - 2), (x + w + 1, y + h + 2, z + ln + 1)]
    b = mission.build_battle
    if b is not None:
        pts += [b.goal[0], b.goal[1], b.player[0], b.player[1]]
    return pts
