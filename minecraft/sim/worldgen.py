"""Seeded terrain: Minecraft-like layers, trees, caves with lava below y=11, and ore veins
with Minecraft 1.11's per-chunk counts and height ranges (diamonds rare, at y 1-15).

Everything is generated with numpy into one ``uint8`` array indexed ``[x, y, z]``; a
128×96×128 world takes well under a second. Flat worlds (``FlatWorldGenerator``) use
Minecraft's superflat layer strings, e.g. ``"3;7,2*3,2;1;"`` (bedrock, 2 dirt, grass),
in a box sized to the mission (``extent``).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from minecraft import blocks as B
from minecraft.sim.extent import Box

SIZE_XZ = 128
SIZE_Y = 96
SEA_LEVEL = 62
LAVA_LEVEL = 10  # cave air at or below this height is lava, as in Minecraft


@dataclass
class Terrain:
    """A generated world.

    Attributes:
        blocks: block ids, indexed ``[x - x0, y, z - z0]``.
        x0: world x of index 0.
        z0: world z of index 0.
        spawn: (x, y, z) feet position of the default spawn.
        mobs: (entity name, x, y, z) animals to spawn.
    """

    blocks: np.ndarray
    x0: int
    z0: int
    spawn: tuple[float, float, float]
    mobs: list[tuple[str, float, float, float]] = field(default_factory=list)


def _value_noise(rng: np.random.Generator, n: int, cell: int) -> np.ndarray:
    """Smooth 2-D value noise in [-1, 1] on an n×n grid with features of ``cell`` blocks."""
    k = n // cell + 2
    grid = rng.uniform(-1.0, 1.0, size=(k, k))
    t = np.arange(n) / cell
    i = t.astype(int)
    f = t - i
    f = f * f * (3 - 2 * f)
    a = grid[i][:, i] * (1 - f)[None, :] + grid[i][:, i + 1] * f[None, :]
    b = grid[i + 1][:, i] * (1 - f)[None, :] + grid[i + 1][:, i + 1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def flat_layers(generator: str) -> list[int]:
    """Block ids, bottom first, of a superflat string like ``"3;7,2*3,2;1;"``.

    Raises:
        ValueError: a layer names a block the simulator does not have.
    """
    parts = generator.split(";")
    spec = parts[1] if len(parts) > 1 else parts[0]
    layers: list[int] = []
    for tok in filter(None, (t.strip() for t in spec.split(","))):
        count = 1
        m = re.match(r"(\d+)[*x](.+)$", tok)  # "2*3" (version 3) or "2x3" (older)
        if m:
            count, tok = int(m.group(1)), m.group(2)
        if tok.startswith("minecraft:"):
            tok = tok[len("minecraft:") :]
        tok = tok.split(":", 1)[0] if tok[:1].isdigit() else tok
        if tok.isdigit():
            if int(tok) not in B.MC_ID:
                raise ValueError(f"flat layer block id {tok} is not simulated")
            bid = B.MC_ID[int(tok)]
        else:
            bid = B.block_id(tok)
        layers.extend([bid] * count)
    return layers


def flat(layers: list[int], box: Box) -> Terrain:
    """A superflat world filling ``box`` with ``layers`` (bottom first), spawn at the origin."""
    arr = np.zeros((box.size_x, box.size_y, box.size_z), dtype=np.uint8)
    layers = layers[: box.size_y]
    arr[:, : len(layers), :] = np.array(layers, dtype=np.uint8)[None, :, None]
    return Terrain(arr, box.x0, box.z0, (0.5, float(len(layers)), 0.5))


def recentre(terrain: Terrain, x: float, z: float, border: int = 8) -> Terrain:
    """Move the terrain so it lies under (x, z) when (x, z) is not already inside it."""
    n = terrain.blocks.shape[0]
    inside_x = terrain.x0 + border <= x < terrain.x0 + n - border
    inside_z = terrain.z0 + border <= z < terrain.z0 + n - border
    if inside_x and inside_z:
        return terrain
    dx, dz = math.floor(x) - n // 2 - terrain.x0, math.floor(z) - n // 2 - terrain.z0
    sx, sy, sz = terrain.spawn
    mobs = [(name, mx + dx, my, mz + dz) for name, mx, my, mz in terrain.mobs]
    return Terrain(terrain.blocks, terrain.x0 + dx, terrain.z0 + dz, (sx + dx, sy, sz + dz), mobs)


def heighten(terrain: Terrain, size_y: int) -> Terrain:
    """The terrain with air added on top up to ``size_y`` blocks."""
    sx, sy, sz = terrain.blocks.shape
    if size_y <= sy:
        return terrain
    arr = np.zeros((sx, size_y, sz), dtype=np.uint8)
    arr[:, :sy, :] = terrain.blocks
    return Terrain(arr, terrain.x0, terrain.z0, terrain.spawn, terrain.mobs)


def generate(
    seed: int, size_xz: int = SIZE_XZ, size_y: int = SIZE_Y, *, diamond_keep: float = 1.0
) -> Terrain:
    """The default world for ``seed`` (same seed, same world).

    Args:
        seed: the world seed.
        size_xz: width and depth in blocks.
        size_y: height in blocks.
        diamond_keep: the fraction of diamond veins kept (``thin_veins``); 1 keeps all.

    Raises:
        ValueError: ``diamond_keep`` outside [0, 1].
    """
    check_keep(diamond_keep)
    rng = np.random.default_rng(seed & 0xFFFFFFFFFFFFFFFF)
    n = size_xz
    height = (
        65.0
        + 6.0 * _value_noise(rng, n, 48)
        + 3.0 * _value_noise(rng, n, 16)
        + 1.0 * _value_noise(rng, n, 6)
    )
    h = np.clip(np.round(height).astype(np.int32), 40, size_y - 16)  # top solid block
    dirt_depth = 3 + (rng.random((n, n)) < 0.4)
    y = np.arange(size_y)[None, :, None]
    hh = h[:, None, :]
    arr = np.zeros((n, size_y, n), dtype=np.uint8)
    arr[y <= hh] = B.STONE_ID
    arr[(y > hh - dirt_depth[:, None, :]) & (y < hh)] = B.ID["dirt"]
    wet = h < SEA_LEVEL
    beach = (h >= SEA_LEVEL - 1) & (h <= SEA_LEVEL + 1)
    top = np.where(wet, B.ID["dirt"], np.where(beach, B.ID["sand"], B.ID["grass"]))
    top = np.where(wet & (rng.random((n, n)) < 0.3), B.ID["gravel"], top)
    xi, zi = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    arr[xi, h, zi] = top
    arr[(y > hh) & (y <= SEA_LEVEL)] = B.WATER
    # Bedrock floor, ragged up to y=4 as in Minecraft.
    arr[:, 0, :] = B.BEDROCK
    for yy in range(1, 5):
        arr[:, yy, :][rng.random((n, n)) < (5 - yy) / 5.0] = B.BEDROCK
    _veins(rng, arr, h, "gravel", per_chunk=4, size=24, y_lo=5, y_hi=60)
    _veins(rng, arr, h, "dirt", per_chunk=4, size=24, y_lo=5, y_hi=60)
    _veins(rng, arr, h, "coal_ore", per_chunk=20, size=12, y_lo=5, y_hi=90)
    _veins(rng, arr, h, "iron_ore", per_chunk=20, size=8, y_lo=1, y_hi=63)
    _veins(rng, arr, h, "gold_ore", per_chunk=2, size=8, y_lo=1, y_hi=31)
    _veins(rng, arr, h, "redstone_ore", per_chunk=8, size=7, y_lo=1, y_hi=15)
    _veins(rng, arr, h, "diamond_ore", per_chunk=1, size=7, y_lo=1, y_hi=15)
    _veins(rng, arr, h, "lapis_ore", per_chunk=1, size=6, y_lo=1, y_hi=30)
    _caves(rng, arr, h)
    _lava_pools(rng, arr, count=max(1, n * n // 4096))
    x0 = z0 = -n // 2
    sx, sz = _spawn_column(h, n)
    _trees(rng, arr, h, (sx, sz))
    spawn = (sx + x0 + 0.5, float(h[sx, sz] + 1), sz + z0 + 0.5)
    mobs = _mobs(rng, arr, h, x0, z0, count=max(4, n * n // 700))
    if diamond_keep < 1.0:
        thin_veins(arr, B.ID["diamond_ore"], diamond_keep, seed)
    return Terrain(arr, x0, z0, spawn, mobs)


def check_keep(keep: float) -> None:
    """Refuse a vein-keeping fraction outside [0, 1].

    Raises:
        ValueError: naming the field and the value.
    """
    if not 0.0 <= keep <= 1.0:  # NaN fails too
        raise ValueError(f"diamond_keep must be within [0, 1], got {keep}")


def veins(arr: np.ndarray, block: int) -> list[list[tuple[int, int, int]]]:
    """The 6-connected groups of ``block`` cells, each sorted, in the order of their first
    cell (array indices)."""
    left = {(int(x), int(y), int(z)) for x, y, z in np.argwhere(arr == block)}
    groups = []
    for start in sorted(left):
        if start not in left:
            continue
        left.discard(start)
        group, todo = [start], [start]
        while todo:
            x, y, z = todo.pop()
            for dx, dy, dz in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
                c = (x + dx, y + dy, z + dz)
                if c in left:
                    left.discard(c)
                    group.append(c)
                    todo.append(c)
        groups.append(sorted(group))
    return groups


def thin_veins(arr: np.ndarray, block: int, keep: float, seed: int) -> int:
    """Keep each 6-connected vein of ``block`` with probability ``keep`` (one draw per
    vein, in the order of ``veins``, from a generator of its own seeded by ``seed``: the
    rest of the world is the same as unthinned); the others become stone.

    Returns:
        the number of veins kept.
    """
    check_keep(keep)
    rng = np.random.default_rng([seed & 0xFFFFFFFFFFFFFFFF, block])
    kept = 0
    for group in veins(arr, block):
        if rng.random() < keep:
            kept += 1
            continue
        x, y, z = np.array(group).T
        arr[x, y, z] = B.STONE_ID
    return kept


def _spawn_column(h: np.ndarray, n: int) -> tuple[int, int]:
    """Dry land nearest the centre."""
    c = n // 2
    xi, zi = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    d = (xi - c) ** 2 + (zi - c) ** 2 + np.where(h > SEA_LEVEL + 1, 0, 10**9)
    i = int(np.argmin(d))
    return i // n, i % n


def _veins(
    rng: np.random.Generator,
    arr: np.ndarray,
    h: np.ndarray,
    name: str,
    *,
    per_chunk: int,
    size: int,
    y_lo: int,
    y_hi: int,
) -> None:
    """Random-walk veins of ``name`` replacing stone (vectorised over all veins)."""
    n, sy, _ = arr.shape
    count = per_chunk * (n // 16) ** 2
    start = np.stack(
        [rng.integers(0, n, count), rng.integers(y_lo, y_hi + 1, count), rng.integers(0, n, count)],
        axis=1,
    )
    steps = np.zeros((count, size, 3), dtype=np.int64)
    axis = rng.integers(0, 3, (count, size))
    sign = rng.choice([-1, 1], (count, size))
    np.put_along_axis(steps, axis[..., None], sign[..., None], axis=2)
    steps[:, 0, :] = 0
    cells = (start[:, None, :] + np.cumsum(steps, axis=1)).reshape(-1, 3)
    ok = (cells >= 0).all(axis=1) & (cells[:, 0] < n) & (cells[:, 2] < n) & (cells[:, 1] < sy)
    cells = cells[ok]
    x, yy, z = cells[:, 0], cells[:, 1], cells[:, 2]
    stone = arr[x, yy, z] == B.STONE_ID
    arr[x[stone], yy[stone], z[stone]] = B.ID[name]


def _caves(rng: np.random.Generator, arr: np.ndarray, h: np.ndarray) -> None:
    """Worm caves: random walks of spheres; air at or below LAVA_LEVEL becomes lava."""
    n, sy, _ = arr.shape
    worms = max(2, n * n // 1400)
    lava_id, air = B.LAVA, B.AIR
    keep = np.zeros(len(B.BLOCKS), dtype=bool)
    keep[[B.BEDROCK, B.WATER]] = True
    for _ in range(worms):
        p = np.array([rng.uniform(0, n), rng.uniform(6, 50), rng.uniform(0, n)])
        yaw, pitch = rng.uniform(0, 2 * np.pi), rng.uniform(-0.3, 0.3)
        for _ in range(int(rng.integers(40, 120))):
            yaw += rng.normal(0, 0.25)
            pitch = float(np.clip(pitch + rng.normal(0, 0.15), -0.6, 0.6))
            p += (np.cos(yaw) * np.cos(pitch), np.sin(pitch), np.sin(yaw) * np.cos(pitch))
            r = rng.uniform(1.2, 2.6)
            lo = np.maximum(np.floor(p - r).astype(int), [0, 1, 0])
            hi = np.minimum(np.ceil(p + r).astype(int) + 1, [n, sy, n])
            if (hi <= lo).any():
                continue
            gx, gy, gz = np.ogrid[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
            inside = (gx + 0.5 - p[0]) ** 2 + (gy + 0.5 - p[1]) ** 2 + (gz + 0.5 - p[2]) ** 2
            sub = arr[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
            # Never break the sea floor or the bedrock.
            under_sea = (h[lo[0] : hi[0], None, lo[2] : hi[2]] < SEA_LEVEL + 1) & (gy > 50)
            mask = (inside < r * r) & ~keep[sub] & ~under_sea
            sub[mask & (gy <= LAVA_LEVEL)] = lava_id
            sub[mask & (gy > LAVA_LEVEL)] = air


def _lava_pools(rng: np.random.Generator, arr: np.ndarray, count: int) -> None:
    """Underground lava lakes in the stone, with an air pocket above, at y 6-12."""
    n = arr.shape[0]
    for _ in range(count):
        c = np.array([rng.integers(8, n - 8), rng.integers(6, 13), rng.integers(8, n - 8)])
        rx, ry, rz = rng.uniform(2.5, 4.5), rng.uniform(1.5, 2.5), rng.uniform(2.5, 4.5)
        lo = c - np.ceil([rx, ry, rz]).astype(int)
        hi = c + np.ceil([rx, ry, rz]).astype(int) + 1
        lo[1] = max(lo[1], 1)
        gx, gy, gz = np.ogrid[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        inside = ((gx - c[0]) / rx) ** 2 + ((gy - c[1]) / ry) ** 2 + ((gz - c[2]) / rz) ** 2 < 1
        sub = arr[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        mask = inside & (sub != B.BEDROCK)
        sub[mask & (gy <= c[1])] = B.LAVA
        sub[mask & (gy > c[1])] = B.AIR


def _tree(arr: np.ndarray, x: int, z: int, base: int, height: int) -> None:
    n, sy, _ = arr.shape
    top = base + height
    if top + 2 >= sy or not (2 <= x < n - 2 and 2 <= z < n - 2):
        return
    leaves = B.ID["leaves"]
    for yy, r in ((top - 2, 2), (top - 1, 2), (top, 1), (top + 1, 1)):
        sub = arr[x - r : x + r + 1, yy, z - r : z + r + 1]
        sub[sub == B.AIR] = leaves
    arr[x, base:top, z] = B.ID["log"]


def _trees(rng: np.random.Generator, arr: np.ndarray, h: np.ndarray, spawn: tuple[int, int]):
    n = arr.shape[0]
    grass = arr[np.arange(n)[:, None], h, np.arange(n)[None, :]] == B.ID["grass"]
    chosen = grass & (rng.random((n, n)) < 1 / 70)
    sx, sz = spawn
    # A few trees near spawn, a short walk away, so every world can start.
    for _ in range(4):
        for _attempt in range(30):
            dx, dz = rng.integers(-9, 10, 2)
            x, z = sx + int(dx), sz + int(dz)
            if 3 <= abs(dx) + abs(dz) and 0 <= x < n and 0 <= z < n and grass[x, z]:
                chosen[x, z] = True
                break
    for x, z in zip(*np.nonzero(chosen), strict=True):
        _tree(arr, int(x), int(z), int(h[x, z]) + 1, int(rng.integers(4, 7)))


def _mobs(
    rng: np.random.Generator, arr: np.ndarray, h: np.ndarray, x0: int, z0: int, count: int
) -> list[tuple[str, float, float, float]]:
    n = arr.shape[0]
    out: list[tuple[str, float, float, float]] = []
    for _ in range(count * 4):
        if len(out) >= count:
            break
        x, z = (int(v) for v in rng.integers(2, n - 2, 2))
        if arr[x, h[x, z], z] == B.ID["grass"] and arr[x, h[x, z] + 1, z] == B.AIR:
            name = "Pig" if rng.random() < 0.5 else "Cow"
            out.append((name, x + x0 + 0.5, float(h[x, z] + 1), z + z0 + 0.5))
    return out
