"""A cheap first-person frame: one ray per pixel walked through the voxels (vectorised
Amanatides–Woo), block colours shaded by face, block outlines and distance fog, animals
and items drawn as boxes.

Rows are returned bottom-up, the OpenGL order in which Malmo sends frames (malmoenv's
``render()`` flips them back); graft's client flips them to the usual top-down order.
"""

from __future__ import annotations

import math
import threading
from functools import lru_cache

import numpy as np

from actors.minecraft import blocks as B
from actors.minecraft.sim.world import World

FOV_Y = 70.0  # Minecraft's default vertical field of view, degrees
MAX_DIST = 32.0
SKY = np.array([135.0, 175.0, 255.0], dtype=np.float32)
ENTITY_COLOURS = {
    "Pig": (240, 160, 160),
    "Cow": (90, 60, 40),
    "Chicken": (240, 240, 240),
    "Sheep": (220, 220, 215),
    "Rabbit": (150, 120, 90),
}
PLAYER_COLOUR = (60, 90, 200)  # another agent of the mission
_SHADE = np.array([0.8, 1.0, 0.65], dtype=np.float32)  # x faces, top faces, z faces


@lru_cache(maxsize=8)
def _camera_grid(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    ty = math.tan(math.radians(FOV_Y) / 2)
    tx = ty * width / height
    u = (2 * (np.arange(width) + 0.5) / width - 1) * tx
    v = (1 - 2 * (np.arange(height) + 0.5) / height) * ty
    uu, vv = np.meshgrid(u, v)
    return uu.ravel().astype(np.float64), vv.ravel().astype(np.float64)


def render(world: World, width: int, height: int, *, depth: bool = False) -> bytes:
    """Render the agent's view.

    Args:
        world: the world to draw.
        width: frame width in pixels.
        height: frame height in pixels.
        depth: append a 4th channel with distance (0 near .. 255 at 32 blocks).

    Returns:
        ``height * width * (3 or 4)`` bytes, rows bottom-up.
    """
    p = world.player
    eye = np.array(p.eye, dtype=np.float64)
    yr, pr = math.radians(p.yaw), math.radians(p.pitch)
    f = np.array([-math.sin(yr) * math.cos(pr), -math.sin(pr), math.cos(yr) * math.cos(pr)])
    r = np.array([-math.cos(yr), 0.0, -math.sin(yr)])
    up = np.cross(r, f)
    uu, vv = _camera_grid(width, height)
    d = f[None, :] + uu[:, None] * r[None, :] + vv[:, None] * up[None, :]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    n = d.shape[0]
    img = np.empty((n, 3), dtype=np.float32)
    img[:] = SKY
    dist = np.full(n, MAX_DIST, dtype=np.float32)
    _march(world, eye, d, img, dist)
    _draw_entities(world, eye, f, r, up, width, height, img, dist)
    fog = (dist / MAX_DIST)[:, None] ** 2
    img = img * (1 - fog) + SKY * fog
    out = img.reshape(height, width, 3)
    if depth:
        dch = np.clip(dist / MAX_DIST * 255.0, 0, 255).reshape(height, width, 1)
        out = np.concatenate([out, dch], axis=2)
    return np.ascontiguousarray(out[::-1]).astype(np.uint8).tobytes()


BOUNDARY = 255  # border cells of the padded copy: rays leaving the world see sky
_STOP = np.zeros(256, dtype=bool)
_STOP[: len(B.OPAQUE)] = B.OPAQUE
_STOP[BOUNDARY] = True
_PALETTE = np.zeros((256, 3), dtype=np.float32)
_PALETTE[: len(B.COLOURS)] = B.COLOURS
_PALETTE[BOUNDARY] = SKY


class _Padded(threading.local):
    """A padded copy of the world (one border cell of ``BOUNDARY``), reused per size and
    per thread (world servers of one process render in their own threads)."""

    def __init__(self) -> None:
        self.buf: np.ndarray = np.zeros(0, dtype=np.uint8)

    def of(self, blocks: np.ndarray) -> np.ndarray:
        shape = tuple(n + 2 for n in blocks.shape)
        if self.buf.shape != shape:
            self.buf = np.full(shape, BOUNDARY, dtype=np.uint8)
        self.buf[1:-1, 1:-1, 1:-1] = blocks
        return self.buf


_PADDED = _Padded()


def _march(world: World, eye: np.ndarray, d: np.ndarray, img: np.ndarray, dist: np.ndarray):
    pad = _PADDED.of(world.blocks)
    px, py, pz = pad.shape
    flat_blocks = pad.reshape(-1)
    n = d.shape[0]
    local = np.floor(eye).astype(np.int64) - np.array([world.x0, 0, world.z0]) + 1
    local = np.clip(local, 0, np.array([px, py, pz]) - 1)
    step = np.where(d > 0, 1, -1).astype(np.int64)
    stride = np.array([py * pz, pz, 1], dtype=np.int64)
    fstep = step * stride
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(d != 0, np.abs(1.0 / d), np.inf)
        tmax = np.where(d != 0, (np.floor(eye) + (step > 0) - eye) / d, np.inf)
    flat = np.full(n, int(local @ stride), dtype=np.int64)
    idx = np.arange(n)
    hit_t = np.full(n, np.inf)
    hit_axis = np.zeros(n, dtype=np.int64)
    hit_bid = np.full(n, BOUNDARY, dtype=np.uint8)
    rows = np.arange(n)
    for _ in range(int(MAX_DIST * 1.8) + 3):
        m = len(idx)
        if m == 0:
            break
        r = rows[:m]
        axis = np.argmin(tmax, axis=1)
        t = tmax[r, axis]
        flat += fstep[r, axis]
        tmax[r, axis] += inv[r, axis]
        bid = flat_blocks[flat]
        stop = _STOP[bid]
        far = t > MAX_DIST
        if stop.any():
            h = np.nonzero(stop)[0]
            hit_t[idx[h]] = t[h]
            hit_axis[idx[h]] = axis[h]
            hit_bid[idx[h]] = bid[h]
            far |= stop
        if far.any():
            keep = ~far
            idx, flat, tmax, inv, fstep = idx[keep], flat[keep], tmax[keep], inv[keep], fstep[keep]
    h = np.nonzero((hit_bid != BOUNDARY) & np.isfinite(hit_t))[0]
    if len(h) == 0:
        return
    th = hit_t[h]
    ax = hit_axis[h]
    col = _PALETTE[hit_bid[h]] * _SHADE[ax][:, None]
    col[(ax == 1) & (d[h, 1] > 0)] *= 0.5  # bottom faces
    # Darken block outlines: where the hit point lies within its face.
    pt = eye[None, :] + d[h] * th[:, None]
    frac = pt - np.floor(pt)
    near = np.minimum(frac, 1 - frac)
    near[np.arange(len(h)), ax] = 1.0
    col[near.min(axis=1) < 0.04] *= 0.7
    img[h] = col
    dist[h] = np.minimum(th, MAX_DIST)


def _draw_entities(world, eye, f, r, up, width, height, img, dist) -> None:
    ty = math.tan(math.radians(FOV_Y) / 2)
    tx = ty * width / height
    things = [(m.body, ENTITY_COLOURS.get(m.name, (200, 200, 200))) for m in world.mobs]
    things += [(it.body, (240, 240, 80)) for it in world.items]
    things += [(o.body, PLAYER_COLOUR) for o in world.others]
    view = img.reshape(height, width, 3)
    dview = dist.reshape(height, width)
    for body, colour in things:
        c = np.array([body.x, body.y + body.height / 2, body.z]) - eye
        z = float(c @ f)
        if z < 0.3 or z > MAX_DIST:
            continue
        x, y = float(c @ r) / (z * tx), float(c @ up) / (z * ty)
        hw = body.half_width / (z * tx)
        hh = body.height / 2 / (z * ty)
        j0, j1 = int((x - hw + 1) / 2 * width), int(math.ceil((x + hw + 1) / 2 * width))
        i0, i1 = int((1 - y - hh) / 2 * height), int(math.ceil((1 - y + hh) / 2 * height))
        j0, j1, i0, i1 = max(j0, 0), min(j1, width), max(i0, 0), min(i1, height)
        if j0 >= j1 or i0 >= i1:
            continue
        dv = dview[i0:i1, j0:j1]
        mask = dv > z
        view[i0:i1, j0:j1][mask] = colour
        dv[mask] = z
