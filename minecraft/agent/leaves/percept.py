"""One step's observation (Malmo's info JSON) parsed into what the tree's leaves read:
position, orientation, vitals, the 15×15×15 grid as block ids, inventory, dropped items
and the crosshair target. Everything comes from the Malmo observation producers."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from minecraft import blocks as B
from minecraft.agent import astar

Cell = tuple[int, int, int]
RADIUS = 7
SIDE = 2 * RADIUS + 1
_ID = {n: i for i, n in enumerate(B.NAMES)}
_UNKNOWN = B.STONE_ID  # a block a real Minecraft has and the tables lack: treat as stone


@dataclass(frozen=True)
class ItemSeen:
    """A dropped item entity: name, position, count, entity id."""

    name: str
    x: float
    y: float
    z: float
    quantity: int
    uid: str


@dataclass
class Percept:
    """The agent's view of one tick.

    Attributes:
        x, y, z: feet position.
        yaw, pitch: degrees (yaw 0 faces +z; pitch > 0 looks down).
        life, food, air: vitals.
        tick: TotalTime.
        ids: grid block ids indexed [y, z, x] (index RADIUS = the agent's block).
        inventory: item -> total count.
        slots: item -> slot indices holding it.
        selected: selected hotbar slot.
        items: dropped items nearby.
        los: the LineOfSight dict ({} when nothing in sight).
        alive: IsAlive.
    """

    x: float
    y: float
    z: float
    yaw: float = 0.0
    pitch: float = 0.0
    life: float = 20.0
    food: int = 20
    air: int = 300
    tick: int = 0
    ids: np.ndarray = field(default_factory=lambda: np.zeros((SIDE, SIDE, SIDE), np.uint8))
    inventory: dict[str, int] = field(default_factory=dict)
    slots: dict[str, list[int]] = field(default_factory=dict)
    selected: int = 0
    items: list[ItemSeen] = field(default_factory=list)
    los: dict[str, Any] = field(default_factory=dict)
    alive: bool = True
    _cats: Optional[np.ndarray] = None

    # ------------------------------------------------------------- geometry
    @property
    def cell(self) -> Cell:
        """The block the feet are in (the grid's centre)."""
        return (math.floor(self.x), math.floor(self.y + 1e-6), math.floor(self.z))

    def to_grid(self, c: Cell) -> Cell:
        """World cell -> grid index (x, y, z), possibly outside 0..SIDE-1."""
        ax, ay, az = self.cell
        return (c[0] - ax + RADIUS, c[1] - ay + RADIUS, c[2] - az + RADIUS)

    def to_world(self, g: Cell) -> Cell:
        """Grid index -> world cell."""
        ax, ay, az = self.cell
        return (g[0] + ax - RADIUS, g[1] + ay - RADIUS, g[2] + az - RADIUS)

    def block(self, c: Cell) -> Optional[int]:
        """Block id at world cell ``c``, or None outside the grid."""
        gx, gy, gz = self.to_grid(c)
        if 0 <= gx < SIDE and 0 <= gy < SIDE and 0 <= gz < SIDE:
            return int(self.ids[gy, gz, gx])
        return None

    def name(self, c: Cell) -> str:
        """Block name at ``c`` ("unknown" outside the grid)."""
        b = self.block(c)
        return B.NAMES[b] if b is not None else "unknown"

    @property
    def categories(self) -> np.ndarray:
        """A* planning categories of the grid."""
        if self._cats is None:
            self._cats = astar.categories_of_ids(self.ids)
        return self._cats

    def find(self, names: Iterable[str]) -> list[Cell]:
        """World cells holding any of ``names``, nearest first."""
        want = [_ID[n] for n in names if n in _ID]
        ys, zs, xs = np.nonzero(np.isin(self.ids, want))
        d = (xs - RADIUS) ** 2 + (ys - RADIUS) ** 2 + (zs - RADIUS) ** 2
        order = np.argsort(d, kind="stable")
        return [self.to_world((int(xs[i]), int(ys[i]), int(zs[i]))) for i in order]

    @property
    def on_ground(self) -> bool:
        """Feet resting on a solid block (any block under the 0.6-wide box counts: a
        player can stand on the edge of a block)."""
        if abs(self.y - round(self.y)) > 1e-3:
            return False
        y = round(self.y) - 1
        for x in {math.floor(self.x - 0.3 + 1e-6), math.floor(self.x + 0.3 - 1e-6)}:
            for z in {math.floor(self.z - 0.3 + 1e-6), math.floor(self.z + 0.3 - 1e-6)}:
                b = self.block((x, y, z))
                if b is not None and B.SOLID[b]:
                    return True
        return False

    def in_liquid(self) -> bool:
        """Feet or head in water or lava."""
        c = self.cell
        for dy in (0, 1):
            b = self.block((c[0], c[1] + dy, c[2]))
            if b is not None and B.LIQUID[b]:
                return True
        return False

    def count(self, item: str) -> int:
        """Items of this kind in the inventory."""
        return self.inventory.get(item, 0)

    def held(self) -> Optional[str]:
        """Item in the selected hotbar slot."""
        for item, idx in self.slots.items():
            if self.selected in idx:
                return item
        return None


def _with_block_cell(los: dict[str, Any], info: Mapping[str, Any]) -> dict[str, Any]:
    """Add ``blockX/Y/Z``, the block the crosshair is on, to a block LineOfSight.

    Malmo reports only the hit point on the block's face. The face is the coordinate
    nearest a whole number; along that axis the block lies on the far side of the face
    in the look direction, along the others it is the one the point lies in.
    """
    if los.get("hitType") != "block" or "blockX" in los:
        return los
    yaw, pitch = (
        math.radians(float(info.get("Yaw", 0.0))),
        math.radians(float(info.get("Pitch", 0.0))),
    )
    look = (-math.sin(yaw) * math.cos(pitch), -math.sin(pitch), math.cos(yaw) * math.cos(pitch))
    point = [float(los[k]) for k in ("x", "y", "z")]
    face = min(range(3), key=lambda i: abs(point[i] - round(point[i])))
    cell = [math.floor(v) for v in point]
    cell[face] = round(point[face]) - (1 if look[face] < 0 else 0)
    los["blockX"], los["blockY"], los["blockZ"] = cell
    return los


def parse(info: Mapping[str, Any], *, grid: str = "cube", entities: str = "entities") -> Percept:
    """Build a Percept from one step's decoded info JSON."""
    p = Percept(
        x=float(info.get("XPos", 0.0)),
        y=float(info.get("YPos", 0.0)),
        z=float(info.get("ZPos", 0.0)),
        yaw=float(info.get("Yaw", 0.0)),
        pitch=float(info.get("Pitch", 0.0)),
        life=float(info.get("Life", 20.0)),
        food=int(info.get("Food", 20)),
        air=int(info.get("Air", 300)),
        tick=int(info.get("TotalTime", 0)),
        selected=int(info.get("currentItemIndex", 0)),
        los=_with_block_cell(dict(info.get("LineOfSight", {})), info),
        alive=bool(info.get("IsAlive", True)),
    )
    names = info.get(grid)
    if names is not None:
        flat = np.fromiter((_ID.get(n, _UNKNOWN) for n in names), dtype=np.uint8)
        p.ids = flat.reshape(SIDE, SIDE, SIDE)
    for s in info.get("inventory", ()):
        p.inventory[s["type"]] = p.inventory.get(s["type"], 0) + int(s["quantity"])
        p.slots.setdefault(s["type"], []).append(int(s["index"]))
    for e in info.get(entities, ()):
        if "quantity" in e:
            p.items.append(
                ItemSeen(e["name"], e["x"], e["y"], e["z"], int(e["quantity"]), str(e["id"]))
            )
    return p
