"""Malmo's ``MazeDecorator``: a field of width × length cells with random cells removed
(gaps) while a path of at most ``width * length - gaps`` cells still joins a start cell
to an end cell; each cell drawn as a scale × scale column of its block on a floor.

The choices are made as Malmo's Java makes them, from Java's ``Random`` and in its order
(the seed as written, ``random`` meaning the world's seed): start and end cells, gaps
removed in random order and put back when they would break the path, the optimal path
found breadth first, then smoothed into subgoals by line of sight. The agents start on
the start block; ``AddQuitProducer`` ends the mission within ``0.5 + scale / 2`` of the
end cell; ``AddNavigationObservations`` adds the subgoals as an
``ObservationFromSubgoalPositionList``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from minecraft.malmo.decorator_specs import MazeBlock, MazeSpec
from minecraft.malmo.mission import DrawOp, Subgoal
from minecraft.malmo.mission_rules import PositionQuit
from minecraft.sim.decorators.decoration import Decoration, block, cuboid, seed_or
from minecraft.sim.decorators.java_random import JavaRandom

Cell = tuple[int, int]


@dataclass(frozen=True)
class MazeLayout:
    """A generated maze, in cells (x across, z along).

    Attributes:
        width: cells across x.
        length: cells across z.
        open: the cells that are not gaps.
        start: the start cell.
        end: the end cell.
        path: the optimal (shortest) path from start to end, both included.
        subgoals: the path smoothed by line of sight (start and end included).
        waypoints: cells that hold a waypoint.
        blocks: the chosen block type of start, end, floor, path, optimal path,
            subgoal, gap and waypoint.
        heights: the chosen heights of start, end, path, optimal path, subgoal, gap.
    """

    width: int
    length: int
    open: frozenset[Cell]
    start: Cell
    end: Cell
    path: tuple[Cell, ...]
    subgoals: tuple[Cell, ...]
    waypoints: frozenset[Cell]
    blocks: dict[str, str]
    heights: dict[str, int]

    def __hash__(self) -> int:
        return hash((self.open, self.start, self.end, self.path))


def _block(b: MazeBlock, rand: JavaRandom) -> str:
    # Java draws a type, then a colour and a variant when the lists are given.
    name = b.types[rand.next_int(len(b.types))] if b.types else "air"
    for choices in (b.colours, b.variants):
        if choices:
            rand.next_int(len(choices))  # colours and variants are not simulated
    return name


def _height(b: MazeBlock, rand: JavaRandom) -> int:
    if b.height_variance == 0:
        return b.height
    return b.height + rand.next_int(2 * b.height_variance + 1) - b.height_variance


def _materials(spec: MazeSpec, path_rand: JavaRandom, block_rand: JavaRandom) -> tuple[dict, dict]:
    names = {}
    for key in ("start", "end", "floor", "path"):
        names[key] = _block(getattr(spec, key), block_rand)
    names["optimal"] = _block(spec.optimal_path, block_rand) if spec.optimal_path else names["path"]
    names["subgoal"] = _block(spec.subgoal, block_rand) if spec.subgoal else names["optimal"]
    names["gap"] = _block(spec.gap, block_rand)
    for way in (spec.waypoint_block, spec.waypoint_item):
        if spec.waypoints and way is not None:
            names["waypoint"] = _block(way, block_rand)
            break
    h = {k: _height(getattr(spec, k), path_rand) for k in ("start", "end", "path")}
    h["optimal"] = _height(spec.optimal_path, path_rand) if spec.optimal_path else h["path"]
    h["subgoal"] = _height(spec.subgoal, path_rand) if spec.subgoal else h["optimal"]
    h["gap"] = _height(spec.gap, path_rand)
    return names, h


class _Grid:
    """The cell graph while the maze is carved (Java's ``Cell[] grid``)."""

    def __init__(self, width: int, length: int, diagonal: bool) -> None:
        self.w, self.l, self.diagonal = width, length, diagonal
        n = width * length
        self.alive = [True] * n
        self.dist = [n] * n
        self.pred: list[Optional[int]] = [None] * n
        self.on_path = [False] * n

    def neighbours(self, i: int) -> list[int]:
        x, z, w, ln = i % self.w, i // self.w, self.w, self.l
        cand = [(x > 0, i - 1), (x < w - 1, i + 1), (z > 0, i - w), (z < ln - 1, i + w)]
        if self.diagonal:
            west, east, north, south = x > 0, x < w - 1, z > 0, z < ln - 1
            cand += [(west and south, i - 1 + w), (west and north, i - 1 - w),
                     (east and south, i + 1 + w), (east and north, i + 1 - w)]  # fmt: skip
        return [j for ok, j in cand if ok and self.alive[j]]

    def shortest(self, start: int, end: int) -> int:
        """Breadth first from ``start`` (Java's search: it stops when ``end`` heads the
        queue); marks nothing. Returns the path's length in cells."""
        n = self.w * self.l
        for i in range(n):
            if self.alive[i]:
                self.dist[i], self.on_path[i], self.pred[i] = n, False, None
        self.dist[start] = 0
        self.on_path[start] = self.on_path[end] = True
        queue, head = [start], 0
        while head < len(queue) and queue[head] != end:
            home = queue[head]
            head += 1
            for j in self.neighbours(home):
                if self.dist[j] > self.dist[home] + 1:
                    queue.append(j)
                    self.dist[j], self.pred[j] = self.dist[home] + 1, home
        return self.dist[end] + 1

    def mark_path(self, start: int, end: int) -> None:
        c = end
        while c != start:
            self.on_path[c] = True
            c = self.pred[c]  # type: ignore[assignment]


def _gap_count(spec: MazeSpec, rand: JavaRandom) -> int:
    # Java's float arithmetic: BigDecimal.floatValue(), nextFloat(), (float)(w * l) * p.
    f32 = np.float32
    p = f32(spec.gap_probability)
    p = f32(float(p) + (float(f32(rand.next_float())) - 0.5) * 2 * float(f32(spec.gap_variance)))
    p = min(max(p, f32(0)), f32(1))
    return int(f32(spec.width * spec.length) * p)


def _ends(spec: MazeSpec, rand: JavaRandom, gaps: int) -> tuple[Cell, Cell, int, int]:
    w, ln, total = spec.width, spec.length, spec.width * spec.length
    longest = total - gaps
    if longest < 2:  # no path could join two cells: Java relaxes the request
        longest, gaps = ln, total - ln
    offset = max(0, ln - longest) if spec.end.fixed_to_edge else 0
    start = (rand.next_int(w), offset + rand.next_int(ln - offset))
    if spec.start.fixed_to_edge:
        start = (start[0], 0)
        if offset:
            longest, gaps = ln, total - ln
    if longest > ln + w:
        end = start
        while end == start:
            end = (rand.next_int(w), rand.next_int(ln))
            if spec.end.fixed_to_edge:
                end = (end[0], ln - 1)
    else:
        r = longest - 1
        lo_x, hi_x = max(0, start[0] - r), min(w - 1, start[0] + r)
        lo_z, hi_z = max(0, start[1] - r), min(ln - 1, start[1] + r)
        while True:
            x = rand.next_int(1 + hi_x - lo_x) + lo_x
            z = rand.next_int(1 + hi_z - lo_z) + lo_z
            if spec.end.fixed_to_edge:
                z = ln - 1
            dx, dz = abs(x - start[0]), abs(z - start[1])
            if spec.allow_diagonal:
                dx, dz = (0, dz) if dx < dz else (dx, 0)
            if dx + dz + 1 <= longest:
                end = (x, z)
                break
    return start, end, gaps, longest


def _carve(g: _Grid, rand: JavaRandom, start: int, end: int, gaps: int, longest: int) -> None:
    """Remove ``gaps`` cells in random order, each only if a path of at most ``longest``
    cells still joins start and end (Java's ``buildPath``)."""
    n = g.w * g.l
    order = list(range(n))
    slot, refresh = 0, True
    while gaps > 0 or refresh:
        target = -1
        if gaps > 0:
            while True:
                if slot >= n:  # every cell tried (Java would throw here)
                    return
                pick = slot + rand.next_int(n - slot)
                target = order[pick]
                order[pick], order[slot] = order[slot], target
                slot += 1
                if target not in (start, end):
                    break
            refresh |= g.on_path[target]
            g.alive[target] = False
        if not refresh:
            gaps -= 1
            continue
        if g.shortest(start, end) <= longest:
            g.mark_path(start, end)
            gaps, refresh = gaps - 1, False
        elif gaps > 0:
            g.alive[target] = True  # it would break the path: put it back
        else:
            return


def _smooth(g: _Grid, path: list[int], walls: bool) -> list[int]:
    """Drop path cells the agent can skip by walking straight (Java's ``findSubgoals``);
    ``walls``: gaps are walls, so the agent's width (0.4) must clear them too."""

    def blocked(cx: int, cz: int) -> bool:
        i = cx + cz * g.w  # Java indexes the flat array, wrapping at the row's end
        return not 0 <= i < len(g.alive) or not g.alive[i]

    def walkable(a: int, b: int) -> bool:
        xa, za = a % g.w + 0.5, a // g.w + 0.5
        xb, zb = b % g.w + 0.5, b // g.w + 0.5
        samples = math.ceil(math.hypot(xb - xa, zb - za) * 5)
        for s in range(samples):
            f = s / samples
            xs, zs = xa + (xb - xa) * f, za + (zb - za) * f
            if blocked(math.floor(xs), math.floor(zs)):
                return False
            if walls:
                for cx in (math.floor(xs - 0.2), math.floor(xs + 0.2)):
                    for cz in (math.floor(zs - 0.2), math.floor(zs + 0.2)):
                        if blocked(cx, cz):
                            return False
        return True

    path = list(path)
    i = 0
    while i + 2 < len(path):
        if walkable(path[i], path[i + 2]):
            del path[i + 1]
        else:
            i += 1
    return path


def layout(spec: MazeSpec, *, world_seed: int) -> MazeLayout:
    """The maze ``spec`` makes (``world_seed`` stands in for a ``random`` seed)."""
    seed = seed_or(spec.seed, world_seed)
    path_rand, block_rand = JavaRandom(seed), JavaRandom(seed)
    if spec.material_seed is not None:
        block_rand = JavaRandom(seed_or(spec.material_seed, world_seed))
    names, heights = _materials(spec, path_rand, block_rand)
    start, end, gaps, longest = _ends(spec, path_rand, _gap_count(spec, path_rand))
    g = _Grid(spec.width, spec.length, spec.allow_diagonal)
    s, e = start[0] + start[1] * g.w, end[0] + end[1] * g.w
    _carve(g, path_rand, s, e, gaps, longest)
    path, c = [e], e
    while c != s and g.pred[c] is not None:
        c = g.pred[c]  # type: ignore[assignment]
        path.append(c)
    path.reverse()
    waypoints = _waypoints(g, path_rand, s, e, spec.waypoints) if spec.waypoints else []
    walls = heights["gap"] > heights["optimal"] and names["gap"] != "air"
    cells = [(i % g.w, i // g.w) for i in range(g.w * g.l)]
    return MazeLayout(
        g.w, g.l, frozenset(cells[i] for i in range(len(cells)) if g.alive[i]), start, end,
        tuple(cells[i] for i in path), tuple(cells[i] for i in _smooth(g, path, walls)),
        frozenset(cells[i] for i in waypoints), names, heights,
    )  # fmt: skip


def _waypoints(g: _Grid, rand: JavaRandom, start: int, end: int, quantity: int) -> list[int]:
    # Java's addWaypoints: every cell reached from the start (the start itself too, once
    # a neighbour leads back to it; never the end), then a partial shuffle.
    seen, cands, queue = set(), [], [start]
    while queue:
        home = queue.pop(0)
        for j in g.neighbours(home):
            if j not in seen and j != end:
                seen.add(j)
                cands.append(j)
                queue.append(j)
    remaining = len(cands)
    for i in range(quantity):
        if remaining <= 0:
            break
        k = rand.next_int(remaining) + i
        cands[i], cands[k] = cands[k], cands[i]
        remaining -= 1
    return cands[: min(quantity, len(cands))]


def build(spec: MazeSpec, *, world_seed: int) -> Decoration:
    """The maze's blocks, the agents' start on the start block, and its quit and
    subgoal producers."""
    m = layout(spec, world_seed=world_seed)
    x0, y0, z0 = spec.origin
    s, n, h = spec.scale, m.blocks, m.heights
    size_x, size_z = m.width * s, m.length * s
    ops: list[DrawOp] = [
        cuboid((x0, y0, z0), (x0 + size_x - 1, y0 + spec.height - 1, z0 + size_z - 1), "air"),
        cuboid((x0, y0, z0), (x0 + size_x - 1, y0, z0 + size_z - 1), n["floor"]),
    ]
    subgoals = set(m.subgoals[1:-1])
    for cx in range(m.width):
        for cz in range(m.length):
            cell = (cx, cz)
            kind = "gap" if cell not in m.open else "optimal" if cell in m.path else "path"
            kind = "subgoal" if cell in subgoals else kind
            kind = "start" if cell == m.start else "end" if cell == m.end else kind
            lo = (x0 + cx * s, y0 + 1, z0 + cz * s)
            if h[kind] >= 1 and n[kind] != "air":
                ops.append(cuboid(lo, (lo[0] + s - 1, y0 + h[kind], lo[2] + s - 1), n[kind]))
            if cell in m.waypoints and kind not in ("start", "end"):
                mx, mz = lo[0] + s // 2, lo[2] + s // 2
                if spec.waypoint_block is not None:
                    ops += [block(mx, y0 + k, mz, n["waypoint"]) for k in range(1, h["path"] + 1)]
                else:
                    ops.append(DrawOp("item", (mx, y0 + h[kind] + 1, mz), n["waypoint"]))

    def centre(c: Cell, y: float) -> tuple[float, float, float]:
        return (s * (c[0] + 0.5) + x0, y, s * (c[1] + 0.5) + z0)

    quits: tuple[PositionQuit, ...] = ()
    if spec.quit_description is not None:
        x, y, z = centre(m.end, 1 + h["optimal"] + y0)
        quits = (PositionQuit(x, y, z, 0.5 + s / 2.0, spec.quit_description),)
    points: tuple[Subgoal, ...] = ()
    if spec.navigation:
        points = tuple(
            Subgoal(*centre(c, 1 + h["optimal"] + y0), 1.0, f"MazeSubpoint_{i}")
            for i, c in enumerate(m.subgoals, 1)
        )
    return Decoration(tuple(ops), centre(m.start, 1 + y0 + h["start"]), quits, points)
