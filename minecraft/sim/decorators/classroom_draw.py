"""The blocks of a ``ClassroomDecorator`` building: its palettes, and each wall and floor
with its obstacle, drawn as Malmo's Java draws them (the same cells, in the same order,
with the same random draws) into a ``Canvas`` of cell -> block type.

A wall runs ``along`` one axis (z for an east-west wall, x for a south-north one) at a
fixed coordinate on the other; ``at(u, y, v)`` is the cell ``u`` along it, ``v`` blocks
off it towards the east or south side (``v = -1``: the west or north room's side).
Torches, doors, stairs and levers keep their type; their facing is not simulated.
"""

from __future__ import annotations

from collections.abc import Callable

from minecraft.malmo.mission import DrawOp
from minecraft.sim.decorators.classroom_rooms import Divider
from minecraft.sim.decorators.decoration import block
from minecraft.sim.decorators.java_random import JavaRandom

Cell = tuple[int, int, int]

_ROLES = ("floor exterior wall light goal moat moat_container door_upper door_lower stairs "
          "stairs_platform ladder puzzle_door_upper puzzle_door_lower trigger platform "
          "hint").split()  # fmt: skip
PALETTES: dict[str, tuple[str, ...]] = {
    "dungeon": ("planks", "cobblestone", "cobblestone", "torch", "gold_block", "lava",
                "cobblestone", "wooden_door", "wooden_door", "stone_stairs", "cobblestone",
                "ladder", "iron_door", "iron_door", "lever", "bookshelf", "gold_ore"),
    "pyramid": ("red_sandstone", "sandstone", "sandstone", "torch", "diamond_block", "lava",
                "sandstone", "acacia_door", "acacia_door", "sandstone_stairs", "sandstone",
                "ladder", "iron_door", "iron_door", "lever", "red_sandstone", "diamond_ore"),
    "igloo": ("snow", "snow", "packed_ice", "torch", "redstone_block", "water", "glowstone",
              "spruce_door", "spruce_door", "spruce_stairs", "packed_ice", "ladder",
              "iron_door", "iron_door", "lever", "snow", "redstone_ore"),
}  # fmt: skip
ROOM_HEIGHT = 4  # the drawings assume 4-block rooms and 2-block floors, as Java's do


def palette(name: str, rand: JavaRandom) -> dict[str, str]:
    """The block of each role: ``random`` draws one of the three (as Java does, first
    thing after seeding); ``default`` and unknown names are the dungeon."""
    if name == "random":
        name = ("dungeon", "pyramid", "igloo")[rand.next_int(3)]
    return dict(zip(_ROLES, PALETTES.get(name, PALETTES["dungeon"]), strict=True))


def op(cell: Cell, name: str) -> DrawOp:
    """A drawn cell as a drawing operation."""
    return block(*cell, name)


class Canvas:
    """The building's cells, the last block drawn in each."""

    def __init__(self, pal: dict[str, str]) -> None:
        self.p = pal
        self.blocks: dict[Cell, str] = {}

    def put(self, cell: Cell, name: str) -> None:
        self.blocks[cell] = name

    def divider(self, d: Divider, rand: JavaRandom) -> None:
        """Draw a wall or floor and its obstacle."""
        if d.kind == "AboveBelow":
            self._floor(d)
        else:
            self._wall(d, rand)

    # ------------------------------------------------------------------ walls
    def _wall(self, d: Divider, rand: JavaRandom) -> None:
        room = (d.a or d.b).box  # type: ignore[union-attr]
        east_west = d.kind == "EastWest"
        lo, hi = (room.z, room.z + room.length) if east_west else (room.x, room.x + room.width)
        c = (room.x - 1 if d.a is not None else room.x + room.width) if east_west else (
            room.z - 1 if d.a is not None else room.z + room.length)  # fmt: skip
        bottom, top = room.y, room.y + room.height

        def at(u: int, y: int, v: int = 0) -> Cell:
            return (c + v, y, u) if east_west else (u, y, c + v)

        p, put = self.p, self.put
        for u in range(lo, hi):
            put(at(u, bottom - 1), p["wall"])
            put(at(u, top), p["wall"])
        for y in range(bottom, top):
            put(at(lo - 1, y), p["wall"])
            put(at(hi, y), p["wall"])

        def solid(u: int, name: str, from_y: int = bottom) -> None:
            for y in range(from_y, top):
                put(at(u, y), name)
            if (u - lo - 1) % 2 == 0 and u < hi - 1:
                put(at(u, bottom + ROOM_HEIGHT - 1, -1), p["light"])
                put(at(u, bottom + ROOM_HEIGHT - 1, 1), p["light"])

        kind, hint = d.obstacle, d.hint
        if kind is None:
            outside = d.a is None or d.b is None
            for u in range(lo, hi):
                solid(u, p["exterior"] if outside else p["wall"])
        elif kind == "Gap":
            start = lo + rand.next_int(hi - lo - 2)
            for u in range(lo, hi):
                if start <= u < start + 2:
                    put(at(u, bottom - 1), p["hint"] if hint else p["wall"])
                    for y in range(bottom, top):
                        put(at(u, y), "air")
                else:
                    solid(u, p["wall"], bottom - 1 if east_west else bottom)
            put(at(start, bottom + ROOM_HEIGHT - 1), p["light"])
            put(at(start + 1, bottom + ROOM_HEIGHT - 1), p["light"])
        elif kind == "Bridge":
            start = lo + rand.next_int(hi - lo - 4) + 1
            mc = p["moat_container"]
            for u in range(lo, hi):
                put(at(u, bottom - 1, -1), mc)
                put(at(u, bottom - 2), mc)
                put(at(u, bottom - 1, 1), mc)
                on = start <= u < start + 2
                put(at(u, bottom - 1), (p["hint"] if hint else mc) if on else p["moat"])
            self._end_lights(at, lo, hi, bottom)
            put(at(lo - 1, bottom - 1), mc)
            put(at(hi, bottom - 1), mc)
        elif kind in ("Door", "Puzzle"):
            door = lo + (rand.next_int(hi - lo - 2) + 1 if kind == "Door"
                         else rand.next_int(hi - lo - 4) + 2)  # fmt: skip
            for u in range(lo, hi):
                solid(u, p["wall"])
            pre = "door" if kind == "Door" else "puzzle_door"
            put(at(door, bottom), p[pre + "_lower"])
            put(at(door, bottom + 1), p[pre + "_upper"])
            if hint:
                put(at(door, bottom - 1), p["hint"])
                if kind == "Door" and east_west:
                    put(at(door, bottom - 1, 1), p["hint"])
            if kind == "Puzzle":
                lever = door - 1 if rand.next_double() < 0.5 else door + 1
                put(at(lever, bottom + 1, -1 if d.room_in is d.b else 1), p["trigger"])
        elif kind == "Jump":
            self._wall_jump(at, lo, hi, bottom, hint, rand)

    def _end_lights(self, at: Callable[..., Cell], lo: int, hi: int, bottom: int) -> None:
        self.put(at(lo, bottom + ROOM_HEIGHT - 1), self.p["light"])
        self.put(at(hi - 1, bottom + ROOM_HEIGHT - 1), self.p["light"])

    def _wall_jump(
        self, at: Callable[..., Cell], lo: int, hi: int, bottom: int, hint: bool,
        rand: JavaRandom,
    ) -> None:  # fmt: skip
        p, put = self.p, self.put
        entrance, leave = rand.next_int(hi - lo - 3), rand.next_int(hi - lo - 3)
        for u in range(lo, hi):
            put(at(u, bottom - 1, -1), p["moat_container"])
            put(at(u, bottom, -1), p["wall"])
            put(at(u, bottom + 1, -1), p["wall"])
            put(at(u, bottom - 2), p["moat_container"])
            put(at(u, bottom - 1, 1), p["moat_container"])
            put(at(u, bottom, 1), p["wall"])
            put(at(u, bottom + 1, 1), p["wall"])
            put(at(u, bottom - 1), p["moat_container"] if u % 2 == 0 else p["moat"])
        self._end_lights(at, lo, hi, bottom)
        for i in range(3):
            put(at(lo + entrance + i, bottom + 1, -1), "air")
            put(at(lo + leave + i, bottom + 1, 1), "air")
        if hint:
            put(at(lo + entrance + 1, bottom, -1), p["hint"])
            put(at(lo + leave + 1, bottom, 1), p["hint"])

    # ----------------------------------------------------------------- floors
    def _floor(self, d: Divider) -> None:
        room = (d.a or d.b).box  # type: ignore[union-attr]
        bottom = room.y - 2 if d.a is not None else room.y + room.height
        p, put = self.p, self.put
        name = p["exterior"] if d.a is None or d.b is None else p["floor"]
        for x in range(room.x, room.x + room.width):
            for y in range(bottom, bottom + 2):
                for z in range(room.z, room.z + room.length):
                    put((x, y, z), name)
        if d.obstacle is None or d.b is None:
            return
        cx, cz, base = 2 * room.x + room.width, 2 * room.z + room.length, d.b.box.y
        if d.obstacle == "Stairs":
            self._stairs(cx // 2 - 1, cz // 2 - 1, base, d.hint)
        elif d.obstacle == "Ladder":
            x, z, top = cx // 2 + 1, cz // 2 + 1, bottom + 2
            for y in range(base, top):
                put((x, y, z), p["wall"])
                put((x, y, z + 1), p["ladder"])
                put((x, y, z + 2), "air")
            put((x, bottom - 1, z - 1), p["light"])
            if d.hint:
                put((x, base - 1, z + 1), p["hint"])
                put((x, bottom + 1, z), p["hint"])
            put((x, top, z), p["light"])
        elif d.obstacle == "Jump":
            self._floor_jump(cx // 2 - 1, cz // 2 - 1, base, d.hint)

    def _steps(self, x: int, b: int, z: int, steps: str) -> None:
        """Cells relative to (x, b, z): ``dx dy dz role`` per line (role ``air``: carve)."""
        for line in steps.strip().splitlines():
            dx, dy, dz, role = line.split()
            name = "air" if role == "air" else self.p[role]
            self.put((x + int(dx), b + int(dy), z + int(dz)), name)

    def _stairs(self, x: int, z: int, b: int, hint: bool) -> None:
        if hint:
            self._steps(x, b, z, "0 -1 -1 hint\n3 5 -1 hint")
        self._steps(
            x,
            b,
            z,
            """
            0 0 0 stairs
            0 1 1 stairs
            0 1 2 stairs_platform
            0 4 2 air
            0 1 3 light
            -1 1 2 light
            1 1 2 light
            1 2 2 stairs
            1 4 2 air
            1 5 2 air
            2 3 2 stairs
            2 4 2 air
            2 5 2 air
            3 3 2 stairs_platform
            3 4 2 air
            3 5 2 air
            3 3 1 light
            3 3 3 light
            3 4 1 stairs
            3 5 1 air
            3 5 0 stairs
            1 6 1 light""",
        )

    def _floor_jump(self, x: int, z: int, b: int, hint: bool) -> None:
        if hint:
            self._steps(x, b, z, "0 -1 -1 hint\n0 5 0 hint")
        self._steps(
            x,
            b,
            z,
            """
            0 0 0 platform
            0 0 1 light
            0 0 2 platform
            0 1 2 platform
            2 2 2 platform
            3 2 2 floor
            3 3 2 floor
            3 3 3 light
            3 3 0 floor
            3 3 -1 light
            2 3 0 platform
            1 5 0 air
            1 6 1 light""",
        )
        for i in range(3):
            self._steps(x, b, z, f"{i} 4 2 air\n{i} 5 2 air\n2 4 {2 - i} air\n2 5 {2 - i} air")
