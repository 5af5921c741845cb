"""DrawingDecorator operations: blocks, cuboids, spheres and lines of blocks, items and
entities, drawn into a new world in the mission's order (later ones overwrite earlier
ones), without waking liquids or dropping sand, as Malmo's ``BlockDrawingHelper`` does.

Drawing blocks removes the items and animals inside them. An item appears at rest in
the middle of its cell and can be picked up after 10 ticks. A sphere fills the cells
within ``radius`` of its centre cell; a line steps along its longest axis, one block a
step, and is kept 4-connected.
"""

from __future__ import annotations

import math

import numpy as np

from minecraft import blocks as B
from minecraft.malmo.mission import DrawOp
from minecraft.sim.state import WorldState


def draw(world: WorldState, op: DrawOp) -> None:
    """Apply one drawing operation to ``world``."""
    c = op.coords
    if op.kind == "item":
        x, y, z = (int(v) + 0.5 for v in c)
        world.drop(op.type.removeprefix("minecraft:"), 1, x, y, z, delay=10, still=True)
    elif op.kind == "entity":
        world.spawn_mob(op.type, c[0], c[1], c[2])
    elif op.kind == "block":
        x, y, z = (int(v) for v in c)
        world.blocks_set_raw(x, y, z, B.block_id(op.type))
        _clear(world, (x, y, z), (x, y, z))
    elif op.kind == "cuboid":
        corners = [int(v) for v in c]
        lo = tuple(min(a, b) for a, b in zip(corners[:3], corners[3:], strict=True))
        hi = tuple(max(a, b) for a, b in zip(corners[:3], corners[3:], strict=True))
        _cuboid(world, lo, hi, B.block_id(op.type))
        _clear(world, lo, hi)
    elif op.kind == "sphere":
        x, y, z, r = (int(v) for v in c)
        _sphere(world, x, y, z, r, B.block_id(op.type))
        _clear(world, (x - r, y - r, z - r), (x + r, y + r, z + r))
    elif op.kind == "line":
        _line(world, [int(v) for v in c], B.block_id(op.type))


def _clear(world: WorldState, lo: tuple[int, ...], hi: tuple[int, ...]) -> None:
    """Remove items and animals whose position lies in the cells lo..hi (inclusive)."""

    def outside(x: float, y: float, z: float) -> bool:
        return not all(a <= v < b + 1 for v, a, b in zip((x, y, z), lo, hi, strict=True))

    world.items = [it for it in world.items if outside(it.body.x, it.body.y, it.body.z)]
    world.mobs = [m for m in world.mobs if outside(m.body.x, m.body.y, m.body.z)]


def _cuboid(world: WorldState, lo: tuple[int, ...], hi: tuple[int, ...], bid: int) -> None:
    sx, sy, sz = world.blocks.shape
    x1, x2 = max(lo[0] - world.x0, 0), min(hi[0] - world.x0 + 1, sx)
    y1, y2 = max(lo[1], 0), min(hi[1] + 1, sy)
    z1, z2 = max(lo[2] - world.z0, 0), min(hi[2] - world.z0 + 1, sz)
    if x1 < x2 and y1 < y2 and z1 < z2:
        world.blocks[x1:x2, y1:y2, z1:z2] = bid


def _sphere(world: WorldState, x: int, y: int, z: int, r: int, bid: int) -> None:
    d = np.arange(-r, r + 1)
    gx, gy, gz = np.meshgrid(d, d, d, indexing="ij")
    for dx, dy, dz in zip(*np.nonzero(gx**2 + gy**2 + gz**2 <= r * r), strict=True):
        world.blocks_set_raw(x + int(d[dx]), y + int(d[dy]), z + int(d[dz]), bid)


def _line(world: WorldState, c: list[int], bid: int) -> None:
    x1, y1, z1, x2, y2, z2 = c
    steps = max(abs(x2 - x1), abs(y2 - y1), abs(z2 - z1), 1)
    px, pz = x1, z1
    for i in range(steps + 1):
        x = math.floor(x1 + i * (x2 - x1) / steps + 0.5)  # Java's Math.round
        y = math.floor(y1 + i * (y2 - y1) / steps + 0.5)
        z = math.floor(z1 + i * (z2 - z1) / steps + 0.5)
        world.blocks_set_raw(x, y, z, bid)
        if x != px and z != pz:
            world.blocks_set_raw(x, y, pz, bid)
        px, pz = x, z
