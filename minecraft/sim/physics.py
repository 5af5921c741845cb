"""Axis-aligned box physics against the voxel array, with Minecraft's per-tick constants.

Bodies move along y, then x, then z (Minecraft's order), in sub-steps shorter than a
block so a fast fall cannot tunnel through the floor; a blocked axis snaps the box to the
block face and zeroes that velocity. There is no step-up: a one-block ledge needs a jump
(jump speed 0.42 reaches 1.25 blocks), a two-block wall cannot be climbed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from minecraft.blocks import SOLID

GRAVITY = 0.08  # blocks/tick², then velocity *= DRAG
DRAG = 0.98
JUMP_SPEED = 0.42
WALK_SPEED = 4.317 / 20.0  # blocks per tick at "move 1"
TERMINAL = 3.92
EPS = 1e-6
_SUBSTEP = 0.45


@dataclass
class Body:
    """A moving box: feet-centre position, velocity and size.

    Attributes:
        x: feet centre x.
        y: feet y (bottom of the box).
        z: feet centre z.
        vx: velocity x, blocks per tick.
        vy: velocity y.
        vz: velocity z.
        half_width: half the box width (0.3 for a player).
        height: box height (1.8 for a player).
        on_ground: resting on a solid block after the last move.
        fall_distance: blocks fallen since last on the ground.
    """

    x: float
    y: float
    z: float
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0
    half_width: float = 0.3
    height: float = 1.8
    on_ground: bool = False
    fall_distance: float = 0.0


class Space:
    """Solid-block queries on a world array ``blocks[x - x0, y, z - z0]``.

    Outside the array horizontally and below y=0 counts as solid (the world's wall);
    above the top counts as air.
    """

    def __init__(self, blocks: np.ndarray, x0: int, z0: int) -> None:
        if not blocks.flags.c_contiguous or blocks.dtype != np.uint8:
            raise ValueError("blocks must be a C-contiguous uint8 array")
        self.blocks = blocks
        self.x0 = x0
        self.z0 = z0
        self.sx, self.sy, self.sz = blocks.shape
        # A zero-copy flat view: single-cell reads in pure Python are far cheaper than
        # numpy scalar indexing, and the few cells a box touches are read one by one.
        self._flat = memoryview(blocks.reshape(-1))  # type: ignore[arg-type]
        self._solid = bytes(SOLID.astype(np.uint8)) + bytes(256 - len(SOLID))

    def box_solid(
        self, minx: float, miny: float, minz: float, maxx: float, maxy: float, maxz: float
    ) -> bool:
        """Whether any solid block overlaps the open box."""
        ix0 = math.floor(minx + EPS) - self.x0
        ix1 = math.floor(maxx - EPS) - self.x0
        iz0 = math.floor(minz + EPS) - self.z0
        iz1 = math.floor(maxz - EPS) - self.z0
        iy0 = math.floor(miny + EPS)
        iy1 = math.floor(maxy - EPS)
        if ix0 < 0 or iz0 < 0 or iy0 < 0 or ix1 >= self.sx or iz1 >= self.sz:
            return True
        sy, sz = self.sy, self.sz
        if iy0 >= sy:
            return False
        iy1 = min(iy1, sy - 1)
        flat, solid = self._flat, self._solid
        for x in range(ix0, ix1 + 1):
            bx = x * sy
            for y in range(iy0, iy1 + 1):
                row = (bx + y) * sz
                for z in range(iz0, iz1 + 1):
                    if solid[flat[row + z]]:
                        return True
        return False

    def body_solid(self, b: Body, x: float, y: float, z: float) -> bool:
        """Whether body ``b`` placed with its feet at (x, y, z) overlaps a solid block."""
        w = b.half_width
        return self.box_solid(x - w, y, z - w, x + w, y + b.height, z + w)

    def move(self, b: Body) -> tuple[bool, bool]:
        """Move ``b`` by its velocity with collisions.

        Returns:
            (hit_horizontal, landed): a wall stopped x or z motion; the body came to rest
            on the ground this tick.
        """
        landed = False
        if b.vy != 0.0:
            hit, b.y = self._axis(b, 1, b.y, b.vy)
            if hit:
                landed = b.vy < 0
                b.vy = 0.0
        hit_h = False
        if b.vx != 0.0:
            hit, b.x = self._axis(b, 0, b.x, b.vx)
            if hit:
                b.vx = 0.0
                hit_h = True
        if b.vz != 0.0:
            hit, b.z = self._axis(b, 2, b.z, b.vz)
            if hit:
                b.vz = 0.0
                hit_h = True
        w = b.half_width
        b.on_ground = landed or self.box_solid(b.x - w, b.y - 0.05, b.z - w, b.x + w, b.y, b.z + w)
        return hit_h, landed

    def _axis(self, b: Body, axis: int, start: float, delta: float) -> tuple[bool, float]:
        steps = max(1, math.ceil(abs(delta) / _SUBSTEP))
        d = delta / steps
        pos = start
        w, h = b.half_width, b.height
        for _ in range(steps):
            cand = pos + d
            if axis == 0:
                box = (cand - w, b.y, b.z - w, cand + w, b.y + h, b.z + w)
            elif axis == 1:
                box = (b.x - w, cand, b.z - w, b.x + w, cand + h, b.z + w)
            else:
                box = (b.x - w, b.y, cand - w, b.x + w, b.y + h, cand + w)
            if self.box_solid(*box):
                lo = 0.0 if axis == 1 else w
                if d > 0:
                    edge = math.floor(cand + (h if axis == 1 else w) - EPS)
                    return True, max(pos, edge - (h if axis == 1 else w))
                edge = math.floor(cand - (0.0 if axis == 1 else w) + EPS) + 1
                return True, min(pos, edge + lo)
            pos = cand
        return False, pos


def apply_gravity(b: Body, in_liquid: bool) -> None:
    """One tick of gravity and drag (slower and damped in water or lava)."""
    if in_liquid:
        b.vy = b.vy * 0.8 - 0.02
    else:
        b.vy = max((b.vy - GRAVITY) * DRAG, -TERMINAL)
