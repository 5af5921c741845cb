"""Malmo's ``ClassroomDecorator``: a building at (0, 55, 0) sliced into a 3-D grid of rooms
by walls and floors, a path of rooms from a start room to the goal room with an obstacle
(gap, lava bridge, door, lever-and-iron-door puzzle, jump; stairs, ladder, parkour) in
each divider on it, and every other room joined back to that path.

The choices are made as Malmo's Java makes them, from Java's ``Random`` seeded with the
``seed`` attribute (an integer; anything else, as in Java a fresh random seed, is the
world's seed here) and in Java's order: the building's size (``complexity``), the
divisions, the depth-first search for the path, hints, obstacles, the drawing
(``classroom_draw``), the goal block and the agents' start. The search keeps Java's
quirk of starting over from the dividers still to try when a branch fails.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import minecraft.sim.decorators.classroom_draw as draw
from minecraft.malmo.decorator_specs import ClassroomSpec
from minecraft.sim.decorators.classroom_rooms import Divider, GridRoom, Room
from minecraft.sim.decorators.decoration import Decoration, cuboid, seed_or
from minecraft.sim.decorators.java_random import JavaRandom

MIN_ROOM = 7
ROOM_HEIGHT = 4
FLOOR_HEIGHT = 2
ORIGIN = (0, 55, 0)
MAX_BUILDING = 3 * (MIN_ROOM + 1)
DIVISIONS = ("SouthNorth", "EastWest", "AboveBelow")
HORIZONTAL = ("Gap", "Bridge", "Door", "Puzzle", "Jump")
VERTICAL = ("Stairs", "Ladder", "Jump")


class ClassroomError(ValueError):
    """Java's ``DecoratorException``: no path of the asked length, or an orphan room
    that cannot be joined."""


@dataclass(frozen=True)
class Passage:
    """A divider with an obstacle, as the agent passes it: from ``room_in`` to
    ``room_out`` through ``kind`` (SouthNorth, EastWest wall or AboveBelow floor)."""

    kind: str
    room_in: Room
    room_out: Room
    obstacle: str
    hint: bool


@dataclass(frozen=True)
class Building:
    """A generated building.

    Attributes:
        rooms: every room (floor by floor, then x, then z).
        path: the passages from the start room to the goal room.
        obstacles: every passage (the path's first, then the joins of the other rooms).
        start_room: where the agents start.
        goal_room: where the goal block is.
        goal: the goal block's cell.
        start: the agents' start (feet).
        palette: the block of each role (``wall``, ``goal``, ``hint``...).
        blocks: the blocks drawn, cell -> block type, after carving the building.
        size: (width, height, length) of the carved building.
    """

    rooms: tuple[Room, ...]
    path: tuple[Passage, ...]
    obstacles: tuple[Passage, ...]
    start_room: Room
    goal_room: Room
    goal: tuple[int, int, int]
    start: tuple[float, float, float]
    palette: dict[str, str] = field(compare=False)
    blocks: dict[tuple[int, int, int], str] = field(compare=False, repr=False)
    size: tuple[int, int, int] = (0, 0, 0)

    def __hash__(self) -> int:
        return hash((self.rooms, self.path, self.goal, self.start))


class Discrete:
    """Malmo's ``Utils.Discrete``: a distribution over counts; ``take`` draws and uses
    up one of a count (so a specification's counts are drawn without replacement)."""

    def __init__(self, rand: JavaRandom, counts: Sequence[float]) -> None:
        self.rand, self.p = rand, [float(c) for c in counts]
        self.total = sum(self.p)
        if self.total == 0:
            self.p[0], self.total = 1.0, 1.0

    @classmethod
    def of_complexity(cls, rand: JavaRandom, count: int, complexity: float) -> Discrete:
        d = cls(rand, [1.0] * count)
        weight = (1 - complexity) / count + complexity
        d.total, part = weight, 1.0 / count
        for i in range(count):
            d.p[i] = min(part, weight)
            weight -= d.p[i]
        return d

    def sample(self) -> int:
        val = self.rand.next_double() * self.total
        for i, p in enumerate(self.p):
            val -= p
            if val < 0:
                return i
        return self.rand.next_int(len(self.p))

    def take(self) -> int:
        i = self.sample()
        if self.p[i] >= 1:
            self.p[i] -= 1
            self.total -= 1
        return i


class _Builder:
    def __init__(self, spec: ClassroomSpec, world_seed: int) -> None:
        seed = seed_or(spec.seed, world_seed)
        if not -(2**31) <= seed < 2**31:  # Java's Integer.parseInt fails: a random seed
            seed = world_seed
        self.rand = r = JavaRandom(seed)
        self.palette = draw.palette(spec.palette, r)
        self.spec_mode = spec.complexity is None
        if spec.complexity is not None:
            building, path, division, obstacle, hint = spec.complexity
            self.building, self.path_complexity = building, path
            self.divisions = Discrete.of_complexity(r, 3, division)
            self.horizontal = Discrete.of_complexity(r, 5, obstacle)
            self.vertical = Discrete.of_complexity(r, 3, obstacle)
            self.hint_likelihood = 1.0 - hint
            self.size = (0, 0, 0)
            self.path_length = 0
        else:
            self.path_complexity = 0.0
            self.divisions = Discrete(r, list(spec.divisions))
            self.horizontal = Discrete(r, list(spec.horizontal))
            self.vertical = Discrete(r, list(spec.vertical))
            self.hint_likelihood = spec.hint_likelihood
            self.size, self.path_length = spec.size, spec.path_length
        self.order = [0, 1, 2, 3, 4, 5]

    def draw_from(self, d: Discrete) -> int:
        return d.take() if self.spec_mode else d.sample()

    def sized(self) -> tuple[int, int, int]:
        if self.size[0]:
            return self.size
        r = self.rand
        w = max(int(r.next_gaussian() * 2 + self.building * MAX_BUILDING + MIN_ROOM), MIN_ROOM)
        ln = max(int(r.next_gaussian() * 2 + self.building * MAX_BUILDING + MIN_ROOM), MIN_ROOM)
        return w, max(max(w, ln) * ROOM_HEIGHT // MIN_ROOM, ROOM_HEIGHT), ln

    def rooms(self, size: tuple[int, int, int]) -> list[GridRoom]:
        (x0, y0, z0), (w, h, ln) = ORIGIN, size
        spans = {"EastWest": [[x0, x0 + w]], "SouthNorth": [[z0, z0 + ln]]}
        floors = [[y0, y0 + ROOM_HEIGHT]]
        while True:
            div = DIVISIONS[self.draw_from(self.divisions)]
            if div == "AboveBelow":
                top = floors[-1][1]
                if top + FLOOR_HEIGHT + ROOM_HEIGHT > y0 + h:
                    break
                floors.append([top + FLOOR_HEIGHT, top + FLOOR_HEIGHT + ROOM_HEIGHT])
                continue
            parts = spans[div]
            counts = [max(0, e - s - 2 * MIN_ROOM) for s, e in parts]
            if sum(counts) == 0:
                break
            i = Discrete(self.rand, counts).sample()
            thick = MIN_ROOM if self.spec_mode else MIN_ROOM + self.rand.next_int(min(3, counts[i]))
            first = parts[i]
            parts.insert(i + 1, [first[0] + thick + 1, first[1]])
            first[1] = first[0] + thick
        xs, zs = spans["EastWest"], spans["SouthNorth"]
        grid = [[[GridRoom(x[0], y[0], z[0], x[1] - x[0], y[1] - y[0], z[1] - z[0]) for z in zs]
                 for x in xs] for y in floors]  # fmt: skip
        for i, layer in enumerate(grid):
            for j, row in enumerate(layer):
                for k, room in enumerate(row):
                    w_ = room.walls
                    if i == 0:
                        w_["below"] = Divider("AboveBelow", room, None)
                    if j == 0:
                        w_["west"] = Divider("EastWest", room, None)
                    if k == 0:
                        w_["north"] = Divider("SouthNorth", room, None)
                    up = grid[i + 1][j][k] if i + 1 < len(grid) else None
                    w_["above"] = Divider("AboveBelow", up, room)
                    if up is not None:
                        up.walls["below"] = w_["above"]
                    east = layer[j + 1][k] if j + 1 < len(layer) else None
                    w_["east"] = Divider("EastWest", east, room)
                    if east is not None:
                        east.walls["west"] = w_["east"]
                    south = row[k + 1] if k + 1 < len(row) else None
                    w_["south"] = Divider("SouthNorth", south, room)
                    if south is not None:
                        south.walls["north"] = w_["south"]
        return [room for layer in grid for row in layer for room in row]

    def shuffle(self) -> None:
        for i in range(5):
            j = self.rand.next_int(6 - i)
            self.order[i], self.order[i + j] = self.order[i + j], self.order[i]

    def find(self, path: list[Divider], room: GridRoom, target: int) -> bool:
        """Java's depth-first ``findPath``: a failed room empties the whole path."""
        if target == 0:
            return True
        room.mark = True
        w = room.walls
        dividers = [w["south"], w["north"], w["east"], w["west"], w["above"], w["below"]]
        for index in self.order:
            d, forward = dividers[index], index % 2 == 0
            before = d.forward
            d.forward = forward
            out = d.room_out
            if out is None or out.mark:
                d.forward = before
                continue
            path.append(d)
            if out.complete or self.find(path, out, target - 1):
                return True
        path.clear()
        return False

    def obstacles(self, path: list[Divider]) -> None:
        first = path[0].room_in
        assert first is not None
        first.complete = True
        for d in path:
            kinds = VERTICAL if d.kind == "AboveBelow" else HORIZONTAL
            dist = self.vertical if d.kind == "AboveBelow" else self.horizontal
            d.obstacle = kinds[self.draw_from(dist)]
            out = d.room_out
            assert out is not None
            out.complete = True


def layout(spec: ClassroomSpec, *, world_seed: int) -> Building:
    """The building ``spec`` makes (``world_seed`` stands in for a random seed).

    Raises:
        ClassroomError: Java's generator fails too (no path of the asked length).
    """
    b = _Builder(spec, world_seed)
    size = b.sized()
    rooms = b.rooms(size)
    b.shuffle()
    length = b.path_length
    length = (int((1 - 0.25 * b.path_complexity) * len(rooms)) - 1 if length == 0
              else min(length, len(rooms) - 1))  # fmt: skip
    path: list[Divider] = []
    joined: list[Divider] = []
    if length > 0:
        for room in rooms:
            for r in rooms:
                r.mark = False
            if b.find(path, room, length):
                break
        if len(path) < length:
            raise ClassroomError("Unable to find path to goal")
        start, goal = path[0].room_in, path[-1].room_out
        for d in path:
            d.hint = b.rand.next_double() < b.hint_likelihood
        b.obstacles(path)
    else:
        start = goal = rooms[0]
        start.complete = True
    assert start is not None and goal is not None
    main = list(path)
    for room in rooms:
        if room.complete:
            continue
        for r in rooms:
            r.mark = False
        path.clear()
        if not b.find(path, room, len(rooms)):
            raise ClassroomError("Unable to join orphan room to goal path")
        for d in path:
            d.forward = not d.forward
        b.obstacles(path)
        joined += path
    canvas = draw.Canvas(b.palette)
    for room in rooms:
        for side in ("south", "north", "east", "west", "below", "above"):
            d = room.walls[side]
            if not d.drawn:
                d.drawn = True
                canvas.divider(d, b.rand)
    g = goal.box
    goal_cell = (g.x + b.rand.next_int(g.width - 4) + 2, g.y, g.z + g.length - 2)
    canvas.put(goal_cell, b.palette["goal"])
    s = start.box
    start_at = (s.x + b.rand.next_int(g.width - 2) + 0.5, 1.0 + s.y, s.z + 0.5)

    def passage(d: Divider) -> Passage:
        assert d.room_in is not None and d.room_out is not None and d.obstacle is not None
        return Passage(d.kind, d.room_in.box, d.room_out.box, d.obstacle, d.hint)

    return Building(
        tuple(r.box for r in rooms), tuple(passage(d) for d in main),
        tuple(passage(d) for d in main + joined), start.box, goal.box, goal_cell, start_at,
        b.palette, canvas.blocks, size,
    )  # fmt: skip


def build(spec: ClassroomSpec, *, world_seed: int) -> Decoration:
    """The building's blocks (the carved volume first) and the agents' start."""
    b = layout(spec, world_seed=world_seed)
    (x0, y0, z0), (w, h, ln) = ORIGIN, b.size
    ops = [cuboid((x0, y0, z0), (x0 + w - 1, y0 + h - 1, z0 + ln - 1), "air")]
    ops += [draw.op(cell, name) for cell, name in b.blocks.items()]
    return Decoration(tuple(ops), b.start)
