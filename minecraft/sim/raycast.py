"""What the crosshair points at: a voxel walk (Amanatides–Woo) from the eye, then boxes of
animals in front of it. Used by attack, use and ObservationFromRay."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from minecraft.blocks import TARGETABLE

REACH = 4.5  # survival reach, blocks


@dataclass(frozen=True)
class Hit:
    """A ray hit.

    Attributes:
        kind: ``"block"``, ``"entity"`` (an animal) or ``"item"``.
        x: hit point x.
        y: hit point y.
        z: hit point z.
        distance: from the eye.
        cell: the block (world coordinates) for block hits.
        normal: the face normal for block hits (where a placed block goes).
        entity: index into the candidate list for entity hits.
    """

    kind: str
    x: float
    y: float
    z: float
    distance: float
    cell: tuple[int, int, int] = (0, 0, 0)
    normal: tuple[int, int, int] = (0, 0, 0)
    entity: int = -1


def cast_block(
    blocks: np.ndarray,
    x0: int,
    z0: int,
    eye: tuple[float, float, float],
    d: tuple[float, float, float],
    max_dist: float,
) -> Optional[Hit]:
    """First targetable block along the ray within ``max_dist`` (liquids are passed)."""
    ox, oy, oz = eye
    dx, dy, dz = d
    cx, cy, cz = math.floor(ox), math.floor(oy), math.floor(oz)
    sx, sy, sz = blocks.shape
    step = [1 if v > 0 else -1 for v in d]
    inv = [abs(1.0 / v) if v != 0 else math.inf for v in d]
    tmax = [
        ((cx + (step[0] > 0)) - ox) / dx if dx != 0 else math.inf,
        ((cy + (step[1] > 0)) - oy) / dy if dy != 0 else math.inf,
        ((cz + (step[2] > 0)) - oz) / dz if dz != 0 else math.inf,
    ]
    t = 0.0
    normal = (0, 0, 0)
    while t <= max_dist:
        ix, iz = cx - x0, cz - z0
        if 0 <= ix < sx and 0 <= iz < sz and 0 <= cy < sy:
            if TARGETABLE[blocks[ix, cy, iz]]:
                return Hit("block", ox + dx * t, oy + dy * t, oz + dz * t, t, (cx, cy, cz), normal)
        elif not (0 <= ix < sx and 0 <= iz < sz) or cy < 0:
            return None
        if tmax[0] < tmax[1] and tmax[0] < tmax[2]:
            t = tmax[0]
            tmax[0] += inv[0]
            cx += step[0]
            normal = (-step[0], 0, 0)
        elif tmax[1] < tmax[2]:
            t = tmax[1]
            tmax[1] += inv[1]
            cy += step[1]
            normal = (0, -step[1], 0)
        else:
            t = tmax[2]
            tmax[2] += inv[2]
            cz += step[2]
            normal = (0, 0, -step[2])
    return None


def ray_box(
    eye: tuple[float, float, float],
    d: tuple[float, float, float],
    box: tuple[float, float, float, float, float, float],
) -> Optional[float]:
    """Distance along the ray to an axis-aligned box, or None (slab test)."""
    t0, t1 = 0.0, math.inf
    for o, v, lo, hi in zip(eye, d, box[:3], box[3:], strict=True):
        if v == 0.0:
            if o < lo or o > hi:
                return None
            continue
        a, b = (lo - o) / v, (hi - o) / v
        if a > b:
            a, b = b, a
        t0, t1 = max(t0, a), min(t1, b)
        if t0 > t1:
            return None
    return t0
