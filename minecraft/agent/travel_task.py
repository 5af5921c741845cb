"""The travel task: a seeded world, a start, a reachable destination 10-30 blocks away,
and the reward the travel controller is trained on (progress, a per-tick cost, a penalty
for being stuck).

A mission is drawn from the world's terrain, given as an argument (``Terrain``; by
default the simulator's generated world of the seed, same seed same world): a
breadth-first search over *walkable* cells (feet and head free, solid ground, no liquid;
moves to the 4 neighbours that a player makes without digging: level, a one-block jump
with head room, a drop of up to 3) finds every cell reachable from the spawn, the
destination is drawn among those at 10-30 blocks, and the search's shortest path is the
mission's **route** (the map a player would be given). Progress is measured along it::

    φ(p) = min over route cells i with |y_i - y| <= 2 and |p - c_i|_xz <= 3 of
           (n - 1 - i) + |p - c_i|_xz

the distance still to go: over the route cells ``i`` (centres ``c_i``) near the feet, the
straight horizontal way to ``c_i`` plus the cells left on the route after it, at its
shortest. Cutting a corner of the (4-neighbour, staircase) route is progress; walking off
the route is not, and neither is being near a later stretch of a route that loops back
(only cells within ``SHORTCUT`` = 3 blocks count: a straight line to a cell 20 blocks
away may cross a cliff). Off the route (no cell that near): the nearest cell's value.

**Stuck** (used by the reward and by ``bench/travel.py`` alike): the best φ reached in
the episode has not improved by ``stuck_progress`` blocks for ``stuck_ticks`` ticks.
The event fires then, and again every ``stuck_ticks`` ticks without such progress.
"""

from __future__ import annotations

import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional, Protocol

import numpy as np

from minecraft import blocks as B

Cell = tuple[int, int, int]
HORIZONTAL = ((1, 0), (-1, 0), (0, 1), (0, -1))
MAX_DROP = 3
SHORTCUT = 3.0
"""Blocks of straight way to a route cell that φ credits (corner cutting)."""


class Terrain(Protocol):
    """What drawing a mission needs to know of a world: its blocks and its spawn.

    The simulator's ``worldgen.Terrain`` is one (``minecraft.sim.worldgen:generate``
    gives a seed's); against a real Minecraft, blocks read from the game around the spawn.
    """

    @property
    def blocks(self) -> np.ndarray:
        """Block ids (``blocks.ID``), indexed ``[x - x0, y, z - z0]``."""
        ...

    @property
    def x0(self) -> int:
        """World x of index 0."""
        ...

    @property
    def z0(self) -> int:
        """World z of index 0."""
        ...

    @property
    def spawn(self) -> tuple[float, float, float]:
        """Feet position (x, y, z) the player spawns at."""
        ...


TerrainSource = Callable[[int], Terrain]
"""A world seed's terrain."""


@dataclass(frozen=True)
class TravelMission:
    """One navigation episode's setting.

    Attributes:
        world_seed: the generated world.
        start: feet position (x, y, z) the agent is placed at (a block centre).
        destination: the feet cell to reach.
        route: walkable shortest path from the start cell to the destination, inclusive.
    """

    world_seed: int
    start: tuple[float, float, float]
    destination: Cell
    route: tuple[Cell, ...]


@dataclass(frozen=True)
class RewardConfig:
    """The travel reward: r = progress_scale·(φ(s) − φ(s')) − tick_cost − stuck_penalty·[stuck]."""

    progress_scale: float = 1.0
    """Reward per block of progress along the route."""
    tick_cost: float = 0.05
    """Cost of every tick (game time is 50 ms a tick): arriving sooner pays."""
    stuck_penalty: float = 2.0
    """Paid each time the stuck event fires."""
    stuck_ticks: int = 40
    """K: ticks without `stuck_progress` blocks of progress that make the agent stuck."""
    stuck_progress: float = 1.0
    """Blocks the best φ must improve by within K ticks to count as progress."""

    def __post_init__(self) -> None:
        for name in ("progress_scale", "tick_cost", "stuck_penalty"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}={getattr(self, name)} must be >= 0")
        if self.stuck_ticks < 1:
            raise ValueError(f"stuck_ticks={self.stuck_ticks} must be >= 1")
        if not self.stuck_progress > 0:
            raise ValueError(
                f"stuck_progress={self.stuck_progress} must be > 0: with 0 any jitter counts "
                "as progress and the agent is never stuck"
            )


# ----------------------------------------------------------------- route and progress
def route_to_go(route: tuple[Cell, ...], x: float, y: float, z: float) -> float:
    """φ: blocks still to walk along ``route`` from feet position (x, y, z)."""
    n = len(route)
    best = nearest = nearest_level = math.inf
    value = value_level = math.inf
    for i, (cx, cy, cz) in enumerate(route):
        d = math.hypot(x - (cx + 0.5), z - (cz + 0.5))
        v = (n - 1 - i) + d
        level = abs(cy - y) <= 2.0
        if level and d <= SHORTCUT:
            best = min(best, v)
        if d <= nearest:  # ties: the later cell
            nearest, value = d, v
        if level and d <= nearest_level:
            nearest_level, value_level = d, v
    if best < math.inf:
        return best
    return value_level if value_level < math.inf else value


class StuckDetector:
    """Fires when the best φ has not improved by ``progress`` within ``ticks`` ticks."""

    def __init__(self, ticks: int, progress: float) -> None:
        self.ticks, self.progress = ticks, progress
        self.reset(math.inf)

    def reset(self, phi: float) -> None:
        """Start an episode at φ = ``phi``."""
        self.best = phi
        self.since = 0
        self.events = 0

    def update(self, phi: float, ticks: int = 1) -> bool:
        """``ticks`` ticks ending at φ = ``phi``; True when the stuck event fires."""
        if phi <= self.best - self.progress:
            self.best, self.since = phi, 0
            return False
        self.since += ticks
        if self.since >= self.ticks:
            self.events += self.since // self.ticks
            self.since %= self.ticks
            return True
        return False

    @property
    def ticks_without_progress(self) -> int:
        return self.since


class TravelReward:
    """Per-tick reward of the travel task (see ``RewardConfig``)."""

    def __init__(self, config: RewardConfig) -> None:
        self.config = config
        self.stuck = StuckDetector(config.stuck_ticks, config.stuck_progress)
        self.phi = 0.0

    def reset(self, phi: float) -> None:
        self.phi = phi
        self.stuck.reset(phi)

    def step(self, phi: float, ticks: int = 1) -> tuple[float, bool]:
        """(reward, stuck event) for ``ticks`` ticks that moved φ from the previous value to
        ``phi`` (more than 1 when a real-time agent missed ticks)."""
        c = self.config
        before = self.stuck.events
        stuck = self.stuck.update(phi, ticks)
        reward = c.progress_scale * (self.phi - phi) - c.tick_cost * ticks
        reward -= c.stuck_penalty * (self.stuck.events - before)
        self.phi = phi
        return reward, stuck


# ----------------------------------------------------------------- missions
class WalkMap:
    """Walkable cells of a world and the moves between them."""

    def __init__(self, terrain: Terrain, centre: Cell, radius: int) -> None:
        """Only the columns within ``radius`` of ``centre`` (x, z) are walkable."""
        blocks = terrain.blocks
        i0 = max(0, centre[0] - terrain.x0 - radius)
        k0 = max(0, centre[2] - terrain.z0 - radius)
        crop = blocks[i0 : i0 + 2 * radius + 1, :, k0 : k0 + 2 * radius + 1]
        free = ~B.SOLID[crop] & ~B.LIQUID[crop]
        ground = B.SOLID[crop] & ~B.LIQUID[crop]
        stand = np.zeros_like(free)
        stand[:, 1:-1, :] = ground[:, :-2, :] & free[:, 1:-1, :] & free[:, 2:, :]
        # Flat bytes: the search reads single cells, which bytes do far faster than numpy.
        self._free, self._stand = free.tobytes(), stand.tobytes()
        self.x0, self.z0 = terrain.x0 + i0, terrain.z0 + k0
        self.nx, self.ny, self.nz = crop.shape

    def _inside(self, x: int, y: int, z: int) -> bool:
        i, k = x - self.x0, z - self.z0
        return 0 <= i < self.nx and 1 <= y < self.ny - 2 and 0 <= k < self.nz

    def _index(self, x: int, y: int, z: int) -> int:
        return ((x - self.x0) * self.ny + y) * self.nz + (z - self.z0)

    def free(self, x: int, y: int, z: int) -> bool:
        """Neither solid nor liquid."""
        return self._free[self._index(x, y, z)] != 0

    def standable(self, c: Cell) -> bool:
        """Feet and head free, solid non-liquid ground below."""
        x, y, z = c
        return self._inside(x, y, z) and self._stand[self._index(x, y, z)] != 0

    def moves(self, c: Cell) -> list[Cell]:
        """Neighbour cells reachable by walking, a one-block jump, or a drop of <= 3."""
        x, y, z = c
        out = []
        head_room = self._inside(x, y + 2, z) and self.free(x, y + 2, z)
        for dx, dz in HORIZONTAL:
            nx, nz = x + dx, z + dz
            if not self._inside(nx, y, nz):
                continue
            up = (nx, y + 1, nz)
            if head_room and self.standable(up):
                out.append(up)
            if not (self.free(nx, y, nz) and self.free(nx, y + 1, nz)):
                continue
            for drop in range(0, MAX_DROP + 1):
                ny = y - drop
                if not self._inside(nx, ny, nz) or not self.free(nx, ny, nz):
                    break
                if self.standable((nx, ny, nz)):
                    out.append((nx, ny, nz))
                    break
        return out

    def reachable(self, start: Cell, radius: int) -> dict[Cell, Optional[Cell]]:
        """Breadth-first search from ``start`` within ``radius`` blocks: cell -> parent."""
        parent: dict[Cell, Optional[Cell]] = {start: None}
        queue = deque([start])
        while queue:
            c = queue.popleft()
            for n in self.moves(c):
                if n in parent:
                    continue
                if abs(n[0] - start[0]) > radius or abs(n[2] - start[2]) > radius:
                    continue
                parent[n] = c
                queue.append(n)
        return parent


def _path(parent: dict[Cell, Optional[Cell]], end: Cell) -> tuple[Cell, ...]:
    out = [end]
    while (p := parent[out[-1]]) is not None:
        out.append(p)
    return tuple(reversed(out))


def draw_missions(
    world_seed: int, count: int, rng: random.Random, *, terrain: Terrain,
    min_dist: float = 10.0, max_dist: float = 30.0,
) -> list[TravelMission]:  # fmt: skip
    """``count`` missions in world ``world_seed`` (its ``terrain``), all starting at its
    spawn, destinations drawn by ``rng``.

    Raises:
        ValueError: the world has no reachable cell at 10-30 blocks from the spawn.
    """
    sx, sy, sz = terrain.spawn
    start_cell = (math.floor(sx), int(round(sy)), math.floor(sz))
    walk = WalkMap(terrain, start_cell, int(max_dist) + 4)
    if not walk.standable(start_cell):  # e.g. a tree grew on the spawn: the nearest free cell
        near = [
            (start_cell[0] + dx, start_cell[1] + dy, start_cell[2] + dz)
            for dx in range(-4, 5)
            for dz in range(-4, 5)
            for dy in range(-3, 4)
        ]
        near = [c for c in near if walk.standable(c)]
        if not near:
            raise ValueError(f"world {world_seed}: nothing standable near the spawn {start_cell}")
        start_cell = min(
            near, key=lambda c: (abs(c[0] - start_cell[0]) + abs(c[2] - start_cell[2]), c)
        )
    parent = walk.reachable(start_cell, radius=int(max_dist) + 4)
    candidates = sorted(
        c
        for c in parent
        if min_dist <= math.hypot(c[0] - start_cell[0], c[2] - start_cell[2]) <= max_dist
    )
    if not candidates:
        raise ValueError(f"world {world_seed}: no walkable destination at {min_dist}-{max_dist}")
    start = (start_cell[0] + 0.5, float(start_cell[1]), start_cell[2] + 0.5)
    return [
        TravelMission(world_seed, start, dest, _path(parent, dest))
        for dest in (rng.choice(candidates) for _ in range(count))
    ]


def mission_pool(
    world_seeds: list[int], per_world: int, seed: int, *, terrain_of: TerrainSource
) -> list[TravelMission]:
    """A fixed list of missions: ``per_world`` destinations in each world, seeded."""
    rng = random.Random(seed)
    return [m for w in world_seeds for m in draw_missions(w, per_world, rng, terrain=terrain_of(w))]


def travel_mission_xml(m: TravelMission, *, time_limit_ticks: int, ms_per_tick: int = 50) -> str:
    """The Malmo mission of ``m``: its seeded world, the start placement, the grid the
    tree plans on (15x15x15 ``cube``), full stats, continuous movement, a time limit."""
    from minecraft.malmo.mission_xml import mission_xml

    return mission_xml(
        width=None,
        height=None,
        ms_per_tick=ms_per_tick,
        time_limit_ms=time_limit_ticks * 50,
        seed=m.world_seed,
        placement=m.start,
        handlers="continuous",
        observations="stats",
    )


def as_array(route: tuple[Cell, ...]) -> np.ndarray:
    """The route as an int array [n, 3] (for plotting and tests)."""
    return np.asarray(route, dtype=np.int64).reshape(-1, 3)
