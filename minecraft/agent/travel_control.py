"""The travel controller μ(s): the obtain-diamond tree's own travel sub-tree (A* on the
15×15×15 grid, then ``control.steer`` towards the next cell) aimed along a mission's
route, and the observation the learned correction π(s) reads.

Each tick ``TreeSteering`` sets the sub-tree's goal to the furthest route cell still in
view (every route cell up to it inside the grid, so a plan along the route exists),
ticks it once, and reads back the continuous commands the leaves wrote:
``μ(s) = [move, strafe, turn, ±0.5 for jump]`` (jump is on when the component is > 0; the
±0.5 leaves room for a correction within [−1, 1] to flip it either way).

Walking only: the action has no ``attack``, so the planner sees every solid block as
unbreakable (``HARD``) and never plans a ``destroy`` step.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import py_trees

from minecraft import blocks as B
from minecraft.agent import astar
from minecraft.agent.leaves.context import Context, forget_namespace, share
from minecraft.agent.leaves.percept import RADIUS, Percept
from minecraft.agent.leaves.travel import travel_subtree
from minecraft.agent.travel_task import Cell

ACTION_NAMES = ("move", "strafe", "turn", "jump")
JUMP_ON, JUMP_OFF = 0.5, -0.5
VIEW = RADIUS - 1  # route cells up to this far (each axis) count as in view

# The compact observation, float32 (see `observation`).
STATS = 8  # the sec. III-D stats: x, y, z / 64, sin, cos yaw, pitch / 90, life, food / 20
CROP_OFFSETS = (-1.6, -0.8, 0.0, 0.8, 1.6)  # blocks, forward and right of the feet
CROP_CELLS = 4 * 5 * 5
EXTRA = 3 + 3 + 3 + 2 + 1  # waypoint, destination, velocity, on ground / in liquid, stuck
OBS_DIM = STATS + CROP_CELLS + EXTRA + len(ACTION_NAMES)
MU = slice(OBS_DIM - len(ACTION_NAMES), OBS_DIM)
"""Where μ(s) sits in the observation: the backbone reads it from there."""
STUCK = STATS + CROP_CELLS + EXTRA - 1
"""Where the stuck counter (ticks without progress / K) sits in the observation."""


def to_agent_frame(dx: float, dz: float, yaw_deg: float) -> tuple[float, float]:
    """A horizontal world vector -> (forward, right) in the agent's frame, the frame of
    ``move``/``strafe`` (world.py: velocity = move·f + strafe·(−f_z, f_x))."""
    yr = math.radians(yaw_deg)
    fx, fz = -math.sin(yr), math.cos(yr)
    return dx * fx + dz * fz, -dx * fz + dz * fx


def local_goal(route: tuple[Cell, ...], progress: int, feet: Cell) -> tuple[int, Cell]:
    """The furthest route cell from index ``progress`` on such that it and every cell
    before it are within ``VIEW`` of ``feet``; returns (its index, the cell)."""
    j = progress
    for i in range(progress, len(route)):
        c = route[i]
        if max(abs(c[0] - feet[0]), abs(c[1] - feet[1]), abs(c[2] - feet[2])) > VIEW:
            break
        j = i
    return j, route[j]


def nearest_route_index(route: tuple[Cell, ...], x: float, y: float, z: float) -> int:
    """Index of the route cell the feet are nearest to (horizontally, |dy| <= 2 first)."""
    best, best_i = math.inf, 0
    for i, (cx, cy, cz) in enumerate(route):
        d = math.hypot(x - cx - 0.5, z - cz - 0.5) + (0.0 if abs(cy - y) <= 2 else 100.0)
        if d < best - 1e-9 or (abs(d - best) <= 1e-9 and i > best_i):
            best, best_i = d, i
    return best_i


class TreeSteering:
    """μ(s): the tree's travel sub-tree, ticked once per observation."""

    def __init__(self) -> None:
        self.ctx = Context(planner=astar.Planner(max_expansions=3000))
        self.tree = py_trees.trees.BehaviourTree(travel_subtree(share(self.ctx, name="travel")))
        self.progress = 0

    def close(self) -> None:
        """Takes the sub-tree off the process-wide blackboard (it ticks no more)."""
        forget_namespace(self.ctx.namespace)

    def reset(self) -> None:
        """A new episode: forget the plan and the stuck counters."""
        self.ctx.memory.clear()
        self.ctx.plan_step = None
        self.progress = 0

    def __call__(self, p: Percept, route: tuple[Cell, ...]) -> tuple[np.ndarray, Optional[Cell]]:
        """Tick the sub-tree on ``p`` towards ``route``.

        Returns:
            (μ(s) as float32 [move, strafe, turn, jump ±0.5], the planned next cell or None).
            The full command sheet (with the tree's pitch) is left in ``self.ctx.commands``.
        """
        ctx = self.ctx
        self.progress = max(self.progress, nearest_route_index(route, p.x, p.y, p.z))
        _, goal = local_goal(route, self.progress, p.cell)
        cats = p.categories.copy()
        cats[cats == astar.SOLID] = astar.HARD  # walking only: nothing to break
        p._cats = cats
        ctx.percept = p
        ctx.goals = frozenset({goal})
        ctx.commands.still()
        ctx.commands.once = []
        self.tree.tick()
        cmd = ctx.commands
        mu = np.array(
            [cmd.move, cmd.strafe, cmd.turn, JUMP_ON if cmd.jump else JUMP_OFF], np.float32
        )
        step = ctx.plan_step[1] if ctx.plan_step is not None else None
        return mu, step


def egocentric_occupancy(p: Percept) -> np.ndarray:
    """{0, 1} occupancy (1 = solid) sampled around the feet in the agent's own frame, the
    frame of move/strafe: at (forward, right) offsets ``CROP_OFFSETS`` from the exact feet
    position and heights dy = -1..2 (ground, feet, head, above), index
    ``(dy+1)*25 + f*5 + r`` (f, r the offsets' indices). Offsets of 0.8 blocks resolve the
    corners the 0.6-wide body catches on, whatever the yaw."""
    yr = math.radians(p.yaw)
    fx, fz = -math.sin(yr), math.cos(yr)
    out = np.zeros((4, 5, 5), np.float32)
    for j, f in enumerate(CROP_OFFSETS):
        for k, r in enumerate(CROP_OFFSETS):
            x = math.floor(p.x + f * fx - r * fz)
            z = math.floor(p.z + f * fz + r * fx)
            for i in range(4):
                b = p.block((x, math.floor(p.y + 1e-6) + i - 1, z))
                out[i, j, k] = 1.0 if b is None else float(B.SOLID[b])
    return out.reshape(-1)


def observation(
    p: Percept,
    *,
    mu: np.ndarray,
    waypoint: Optional[Cell],
    destination: Cell,
    previous: Optional[tuple[float, float, float]],
    stuck_fraction: float,
    elapsed: int = 1,
) -> np.ndarray:
    """The correction network's input, float32 [OBS_DIM]::

    [0:8]     the sec. III-D stats (grid_encoding: position / 64, sin, cos yaw, pitch / 90,
              life / 20, food / 20)
    [8:108]   occupancy {0, 1} of the cells dx, dz in -2..2, dy in -1..2 around the
              feet (the sec. III-D cube's cells nearest the body), index
              (dy+1)*25 + (dz+2)*5 + (dx+2)
    [108:111] next A* cell centre minus feet, agent frame (forward, right) / 2, dy / 2
              (zeros when there is no plan)
    [111:114] destination, agent frame (forward, right) / 32, dy / 8
    [114:117] velocity since the last step (``elapsed`` ticks ago), per tick: agent frame
              / walk speed, dy / 0.5
    [117:119] on ground, in liquid
    [119]     ticks without progress / K (the stuck counter)
    [120:124] μ(s)
    """
    yaw = p.yaw
    stats = np.array(
        [
            p.x / 64.0,
            p.y / 64.0,
            p.z / 64.0,
            math.sin(math.radians(yaw)),
            math.cos(math.radians(yaw)),
            p.pitch / 90.0,
            p.life / 20.0,
            p.food / 20.0,
        ],
        np.float32,
    )
    crop = egocentric_occupancy(p)
    extra = np.zeros(EXTRA, np.float32)
    if waypoint is not None:
        f, s = to_agent_frame(waypoint[0] + 0.5 - p.x, waypoint[2] + 0.5 - p.z, yaw)
        extra[0:3] = (f / 2.0, s / 2.0, (waypoint[1] - p.y) / 2.0)
    f, s = to_agent_frame(destination[0] + 0.5 - p.x, destination[2] + 0.5 - p.z, yaw)
    extra[3:6] = (f / 32.0, s / 32.0, (destination[1] - p.y) / 8.0)
    if previous is not None:
        walk = 4.317 / 20.0 * elapsed
        f, s = to_agent_frame(p.x - previous[0], p.z - previous[2], yaw)
        extra[6:9] = (f / walk, s / walk, (p.y - previous[1]) / (0.5 * elapsed))
    extra[9:11] = (float(p.on_ground), float(p.in_liquid()))
    extra[11] = stuck_fraction
    return np.concatenate([stats, crop, extra, np.asarray(mu, np.float32)])


def compose_commands(action: np.ndarray, pitch: float) -> str:
    """The applied action [move, strafe, turn, jump] (clipped to [−1, 1]; jump when > 0)
    plus the tree's pitch, as ContinuousMovementCommands."""
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return (
        f"move {a[0]:.3f}\nstrafe {a[1]:.3f}\nturn {a[2]:.3f}\npitch {pitch:.3f}\n"
        f"jump {int(a[3] > 0)}"
    )
