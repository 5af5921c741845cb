"""A cheap first-person frame: one ray per pixel walked through the voxels (Amanatides–Woo,
compiled with numba), block colours shaded by face, block outlines and distance fog, animals
and items drawn as boxes.

Rows are returned bottom-up, the OpenGL order in which Malmo sends frames (malmoenv's
``render()`` flips them back); graft's client flips them to the usual top-down order.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

from minecraft import blocks as B
from minecraft.compiled import compile_once
from minecraft.sim.world import World

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
ITEM_COLOUR = (240, 240, 80)  # a dropped item
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
    up = np.array(  # r × f
        [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]]
    )
    uu, vv = _camera_grid(width, height)
    things = [(m.body, ENTITY_COLOURS.get(m.name, (200, 200, 200))) for m in world.mobs]
    things += [(it.body, ITEM_COLOUR) for it in world.items]
    things += [(o.body, PLAYER_COLOUR) for o in world.others]
    boxes = np.array(
        [(b.x, b.y + b.height / 2, b.z, b.half_width, b.height) for b, _ in things], np.float64
    ).reshape(-1, 5)
    colours = np.array([c for _, c in things], np.float32).reshape(-1, 3)
    out = np.empty((height, width, 4 if depth else 3), dtype=np.uint8)
    origin = np.array([world.x0, 0, world.z0], dtype=np.float64)
    _draw(world.blocks, eye, eye - origin, f, r, up, uu, vv, boxes, colours, _STOP, _PALETTE,
          _SHADE, SKY, out)  # fmt: skip
    return out.tobytes()


_STOP = np.zeros(256, dtype=np.bool_)
_STOP[: len(B.OPAQUE)] = B.OPAQUE
_PALETTE = np.zeros((256, 3), dtype=np.float32)
_PALETTE[: len(B.COLOURS)] = B.COLOURS
_STEPS = int(MAX_DIST * 1.8) + 3  # cells a ray may cross within MAX_DIST (3 axes)


def warm_up() -> None:
    """Compiles the frame's kernels (or loads them from numba's cache), so a world
    server's first frame does not wait for the compiler.

    One process compiles at a time (``compiled.compile_once``)."""
    compile_once("render", _draw, compile_kernels)


def compile_kernels() -> None:
    """Draws a 1-pixel frame: numba compiles the kernels, or loads them from its cache."""
    blocks = np.zeros((2, 2, 2), dtype=np.uint8)
    v = np.zeros(3)
    grid = np.zeros(1)
    boxes, colours = np.zeros((0, 5)), np.zeros((0, 3), dtype=np.float32)
    out = np.empty((1, 1, 3), dtype=np.uint8)
    _draw(blocks, v, v, v, v, v, grid, grid, boxes, colours, _STOP, _PALETTE, _SHADE, SKY, out)


@numba.njit(cache=True, nogil=True)
def _march_rays(blocks, eye, d, stop, palette, shade, img, dist):  # pragma: no cover
    # Amanatides & Woo (1987): step from cell to cell along the ray, always across the
    # nearest cell boundary. Compiled (numba): a world server draws a frame every tick.
    nx, ny, nz = blocks.shape
    cell0 = np.floor(eye)
    cell, step, t_max, t_delta = np.empty(3), np.empty(3), np.empty(3), np.empty(3)
    for p in range(d.shape[0]):
        cell[:] = cell0
        for a in range(3):
            step[a] = 1.0 if d[p, a] > 0 else -1.0
            if d[p, a] != 0:
                t_delta[a] = abs(1.0 / d[p, a])
                t_max[a] = (cell0[a] + (1.0 if d[p, a] > 0 else 0.0) - eye[a]) / d[p, a]
            else:
                t_delta[a] = np.inf
                t_max[a] = np.inf
        for _ in range(_STEPS):
            axis = 0
            if t_max[1] < t_max[axis]:
                axis = 1
            if t_max[2] < t_max[axis]:
                axis = 2
            t = t_max[axis]
            if t > MAX_DIST:
                break
            cell[axis] += step[axis]
            t_max[axis] += t_delta[axis]
            x, y, z = int(cell[0]), int(cell[1]), int(cell[2])
            if not (0 <= x < nx and 0 <= y < ny and 0 <= z < nz):
                break  # left the world: sky
            bid = blocks[x, y, z]
            if not stop[bid]:
                continue
            k = shade[axis]
            if axis == 1 and d[p, 1] > 0:
                k *= 0.5  # bottom faces
            # Darken block outlines: where the hit point lies near its face's edge.
            near = 1.0
            for a in range(3):
                if a != axis:
                    q = eye[a] + d[p, a] * t
                    frac = q - np.floor(q)
                    near = min(near, frac, 1.0 - frac)
            if near < 0.04:
                k *= 0.7
            for c in range(3):
                img[p, c] = palette[bid, c] * k
            dist[p] = t
            break


@numba.njit(cache=True, nogil=True)
def _draw(blocks, eye, eye_in_blocks, f, r, up, uu, vv, boxes, colours, stop, palette, shade,
          sky, out):  # pragma: no cover  # fmt: skip
    # One frame, compiled: each pixel's ray, the voxels it crosses, the animals, items and
    # agents in front of the first block it hits (as boxes), distance fog, and the bytes
    # (rows bottom-up, Malmo's order; a 4th channel: distance).
    height, width, channels = out.shape
    n = height * width
    d = np.empty((n, 3))
    for p in range(n):
        norm = 0.0
        for a in range(3):
            d[p, a] = f[a] + uu[p] * r[a] + vv[p] * up[a]
            norm += d[p, a] * d[p, a]
        d[p] /= math.sqrt(norm)
    img = np.empty((n, 3), dtype=np.float32)
    img[:] = sky
    dist = np.full(n, MAX_DIST, dtype=np.float32)
    _march_rays(blocks, eye_in_blocks, d, stop, palette, shade, img, dist)
    ty = math.tan(math.radians(FOV_Y) / 2)
    tx = ty * width / height
    for k in range(boxes.shape[0]):
        cx, cy, cz = boxes[k, 0] - eye[0], boxes[k, 1] - eye[1], boxes[k, 2] - eye[2]
        z = cx * f[0] + cy * f[1] + cz * f[2]
        if z < 0.3 or z > MAX_DIST:
            continue
        x = (cx * r[0] + cy * r[1] + cz * r[2]) / (z * tx)
        y = (cx * up[0] + cy * up[1] + cz * up[2]) / (z * ty)
        hw = boxes[k, 3] / (z * tx)
        hh = boxes[k, 4] / 2 / (z * ty)
        j0 = max(int((x - hw + 1) / 2 * width), 0)
        j1 = min(int(math.ceil((x + hw + 1) / 2 * width)), width)
        i0 = max(int((1 - y - hh) / 2 * height), 0)
        i1 = min(int(math.ceil((1 - y + hh) / 2 * height)), height)
        for i in range(i0, i1):
            for j in range(j0, j1):
                q = i * width + j
                if dist[q] > z:
                    img[q] = colours[k]
                    dist[q] = z
    for i in range(height):
        row = height - 1 - i  # bottom-up
        for j in range(width):
            q = i * width + j
            fog = np.float32((dist[q] / np.float32(MAX_DIST)) ** 2)
            for ch in range(3):
                out[row, j, ch] = np.uint8(img[q, ch] * (np.float32(1) - fog) + sky[ch] * fog)
            if channels == 4:
                v = dist[q] / np.float32(MAX_DIST) * np.float32(255.0)
                out[row, j, 3] = np.uint8(min(max(v, np.float32(0)), np.float32(255)))
