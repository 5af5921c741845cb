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
    up = np.array(  # r × f (np.cross costs more than the whole ray march)
        [r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]]
    )
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


_STOP = np.zeros(256, dtype=np.bool_)
_STOP[: len(B.OPAQUE)] = B.OPAQUE
_PALETTE = np.zeros((256, 3), dtype=np.float32)
_PALETTE[: len(B.COLOURS)] = B.COLOURS
_STEPS = int(MAX_DIST * 1.8) + 3  # cells a ray may cross within MAX_DIST (3 axes)


def _march(world: World, eye: np.ndarray, d: np.ndarray, img: np.ndarray, dist: np.ndarray):
    """Each pixel's ray through the voxels: the first opaque block's colour, shaded by
    its face, into ``img``, and its distance into ``dist`` (rays that hit nothing keep
    the sky and ``MAX_DIST``)."""
    origin = np.array([world.x0, 0, world.z0], dtype=np.float64)
    _march_rays(world.blocks, eye - origin, d, _STOP, _PALETTE, _SHADE, img, dist)


def warm_up() -> None:
    """Compiles the ray march (or loads it from numba's cache), so a world server's first
    frame does not wait for the compiler."""
    blocks = np.zeros((2, 2, 2), dtype=np.uint8)
    d = np.ones((1, 3)) / math.sqrt(3.0)
    img, dist = np.empty((1, 3), dtype=np.float32), np.empty(1, dtype=np.float32)
    _march_rays(blocks, np.full(3, 0.5), d, _STOP, _PALETTE, _SHADE, img, dist)


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
