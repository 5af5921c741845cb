"""The rooms and dividers of a ``ClassroomDecorator`` building, as its layout
(``classroom``) makes them and its drawing (``classroom_draw``) draws them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class Room:
    """A room's lowest air corner and its size in blocks."""

    x: int
    y: int
    z: int
    width: int
    height: int
    length: int


class GridRoom:
    """A room of the building grid while the layout is made: its box and its walls."""

    def __init__(self, x: int, y: int, z: int, w: int, h: int, ln: int) -> None:
        self.box = Room(x, y, z, w, h, ln)
        self.complete = self.mark = False
        self.walls: dict[str, Divider] = {}  # south north east west above below


class Divider:
    """A wall or floor between ``a`` (south, east or above) and ``b`` (north, west or
    below); either may be None (the outside). ``forward``: passed from b to a."""

    def __init__(self, kind: str, a: Optional[GridRoom], b: Optional[GridRoom]) -> None:
        self.kind, self.a, self.b = kind, a, b
        self.forward = self.hint = self.drawn = False
        self.obstacle: Optional[str] = None

    @property
    def room_in(self) -> Optional[GridRoom]:
        return self.b if self.forward else self.a

    @property
    def room_out(self) -> Optional[GridRoom]:
        return self.a if self.forward else self.b
