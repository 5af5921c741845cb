"""Steering and aiming: the continuous movement commands that take the agent to a block
centre and point the crosshair at a block face.

``steer`` is the tree's own controller μ(s) for a move (the travel task's backbone RL
learns a correction on top of it): holonomic (move and strafe in the agent's frame, so turning is
not needed to walk), proportional near the target, jumping when the next cell is higher.
"""

from __future__ import annotations

import math

from minecraft.agent.leaves.context import Commands
from minecraft.agent.leaves.percept import Cell, Percept

TURN_DEGS_PER_TICK = 9.0  # turnSpeedDegs 180 at turn 1, 20 ticks/s
WALK_PER_TICK = 4.317 / 20.0
EYE = 1.62
ITEM_MARGIN = 0.5  # blocks: an item this close to a block's box lies on it
BLOCK_REACH = 4.5  # blocks from the eye: a survival player's reach


def steer(p: Percept, cell: Cell, cmd: Commands) -> float:
    """Walk (and jump when ``cell`` is higher) towards the centre of ``cell``.

    Returns:
        The horizontal distance left to the centre.
    """
    tx, tz = cell[0] + 0.5, cell[2] + 0.5
    dx, dz = tx - p.x, tz - p.z
    dist = math.hypot(dx, dz)
    # Full speed far off; near the centre, the speed that covers what is left in the
    # ``cmd.hold`` ticks the command is held.
    scale = min(1.0, dist / (WALK_PER_TICK * cmd.hold)) / dist if dist > 1e-6 else 0.0
    vx, vz = dx * scale, dz * scale
    yr = math.radians(p.yaw)
    fx, fz = -math.sin(yr), math.cos(yr)
    # velocity = move·(fx, fz) + strafe·(-fz, fx)  (world.py); invert the rotation.
    cmd.move = max(-1.0, min(1.0, vx * fx + vz * fz))
    cmd.strafe = max(-1.0, min(1.0, -vx * fz + vz * fx))
    cmd.jump = cell[1] > p.cell[1]
    return dist


def face_point(p: Percept, cell: Cell) -> tuple[float, float, float]:
    """Centre of the face of ``cell`` that looks most directly at the agent's eye."""
    ex, ey, ez = p.x, p.y + EYE, p.z
    cx, cy, cz = cell[0] + 0.5, cell[1] + 0.5, cell[2] + 0.5
    d = (ex - cx, ey - cy, ez - cz)
    axis = max(range(3), key=lambda i: abs(d[i]))
    pt = [cx, cy, cz]
    pt[axis] += 0.5 * math.copysign(1.0, d[axis]) * 0.98
    return pt[0], pt[1], pt[2]


def aim(p: Percept, point: tuple[float, float, float], cmd: Commands) -> float:
    """Turn and pitch towards ``point``.

    Returns:
        The largest remaining angle error in degrees.
    """
    dx, dy, dz = point[0] - p.x, point[1] - (p.y + EYE), point[2] - p.z
    yaw = math.degrees(math.atan2(-dx, dz)) % 360.0
    pitch = -math.degrees(math.atan2(dy, math.hypot(dx, dz)))
    dyaw = (yaw - p.yaw + 180.0) % 360.0 - 180.0
    dpitch = pitch - p.pitch
    cmd.turn = turn_rate(dyaw, cmd.hold)
    cmd.pitch = turn_rate(dpitch, cmd.hold)
    return max(abs(dyaw), abs(dpitch))


def turn_rate(error_degs: float, hold: int) -> float:
    """The turn (or pitch) command in [-1, 1] that closes ``error_degs`` in ``hold`` ticks."""
    return max(-1.0, min(1.0, error_degs / (TURN_DEGS_PER_TICK * hold)))


def looking_at(p: Percept, cell: Cell) -> bool:
    """The crosshair's block (ObservationFromRay) is ``cell`` and within reach."""
    los = p.los
    return (
        los.get("hitType") == "block"
        and bool(los.get("inRange"))
        and (los.get("blockX"), los.get("blockY"), los.get("blockZ")) == cell
    )


def item_on(p: Percept, cell: Cell) -> bool:
    """The crosshair's ray stops at a dropped item lying on or in ``cell`` (within
    ``ITEM_MARGIN`` of its box), and ``cell``'s face is within reach. Malmo's ray
    observation reports items, but hands reach through them: aimed at that face, an
    attack still digs ``cell``."""
    los = p.los
    if los.get("hitType") != "item":
        return False
    if math.dist((p.x, p.y + EYE, p.z), face_point(p, cell)) > BLOCK_REACH:
        return False
    try:
        at = (float(los["x"]), float(los["y"]), float(los["z"]))
    except (KeyError, TypeError, ValueError):
        return False
    return all(c - ITEM_MARGIN <= v <= c + 1 + ITEM_MARGIN for v, c in zip(at, cell, strict=True))
