"""A mission's world generators beyond drawing (``MazeDecorator``, ``ClassroomDecorator``,
``BuildBattleDecorator``), parsed into plain data with the defaults of Malmo's schema.

What a generator builds from its specification is the world's business (real Minecraft's
Java, or the simulator's ``sim/decorators``); here the XML, already checked against the
schema, is only read.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Optional

Cell = tuple[int, int, int]


@dataclass(frozen=True)
class MazeBlock:
    """A ``MazeBlock``: the block types (one is chosen per maze), colours and variants
    to choose from, the column's height and its random variance."""

    types: tuple[str, ...] = ()
    colours: tuple[str, ...] = ()
    variants: tuple[str, ...] = ()
    height: int = 1
    height_variance: int = 0
    fixed_to_edge: bool = False


@dataclass(frozen=True)
class MazeSpec:
    """A ``MazeDecorator``.

    Attributes:
        seed: ``Seed`` as written (digits, or ``random``).
        material_seed: ``MaterialSeed`` as written, or None (the master seed's stream).
        allow_diagonal: ``AllowDiagonalMovement``.
        width: cells across x.
        length: cells across z.
        height: blocks of air cleared above the floor.
        scale: blocks per cell side.
        origin: the floor's lowest corner (x, y, z).
        start: ``StartBlock``.
        end: ``EndBlock``.
        path: ``PathBlock``.
        floor: ``FloorBlock``.
        gap: ``GapBlock``.
        optimal_path: ``OptimalPathBlock`` (None: drawn as the path).
        subgoal: ``SubgoalBlock`` (None: drawn as the optimal path).
        waypoints: ``Waypoints`` quantity (0: none).
        waypoint_block: ``WaypointBlock``, or None.
        waypoint_item: ``WaypointItem`` (types, colours, variants), or None.
        gap_probability: ``GapProbability``.
        gap_variance: its ``variance``.
        quit_description: ``AddQuitProducer`` description, or None without it.
        navigation: ``AddNavigationObservations`` is present.
        at: how many drawing operations come before it (decorators run in XML order).
    """

    seed: str
    material_seed: Optional[str]
    allow_diagonal: bool
    width: int
    length: int
    height: int
    scale: int
    origin: Cell
    start: MazeBlock
    end: MazeBlock
    path: MazeBlock
    floor: MazeBlock
    gap: MazeBlock
    optimal_path: Optional[MazeBlock]
    subgoal: Optional[MazeBlock]
    waypoints: int
    waypoint_block: Optional[MazeBlock]
    waypoint_item: Optional[MazeBlock]
    gap_probability: float
    gap_variance: float
    quit_description: Optional[str]
    navigation: bool
    at: int = 0


@dataclass(frozen=True)
class ClassroomSpec:
    """A ``ClassroomDecorator``: either ``complexity`` (building, path, division,
    obstacle, hint in [0, 1]) or the ``specification`` fields.

    Attributes:
        seed: the ``seed`` attribute as written, or None.
        palette: ``default``, ``random``, ``dungeon``, ``pyramid`` or ``igloo``.
        complexity: (building, path, division, obstacle, hint), or None.
        size: (width, height, length) of a specification.
        path_length: ``pathLength`` (0: every room on the path).
        divisions: (southNorth, eastWest, aboveBelow) counts.
        horizontal: (gap, bridge, door, puzzle, jump) counts.
        vertical: (stairs, ladder, jump) counts.
        hint_likelihood: ``hintLikelihood``.
        at: how many drawing operations come before it.
    """

    seed: Optional[str]
    palette: str = "default"
    complexity: Optional[tuple[float, float, float, float, float]] = None
    size: tuple[int, int, int] = (0, 0, 0)
    path_length: int = 0
    divisions: tuple[int, int, int] = (0, 0, 0)
    horizontal: tuple[int, int, int, int, int] = (0, 0, 0, 0, 0)
    vertical: tuple[int, int, int] = (0, 0, 0)
    hint_likelihood: float = 0.0
    at: int = 0


@dataclass(frozen=True)
class BuildBattleSpec:
    """A ``BuildBattleDecorator``: the goal structure's and the player's copy's
    inclusive bounds, and the block types that mark right and wrong blocks (or None)."""

    goal: tuple[Cell, Cell]
    player: tuple[Cell, Cell]
    correct: Optional[str] = None
    incorrect: Optional[str] = None


def _tag(e: ET.Element) -> str:
    return e.tag.rsplit("}", 1)[-1]


def _kids(e: ET.Element) -> dict[str, ET.Element]:
    return {_tag(c): c for c in e}


def _text(e: Optional[ET.Element], default: str = "") -> str:
    return default if e is None or e.text is None else e.text.strip()


def _words(e: ET.Element, attr: str) -> tuple[str, ...]:
    return tuple(w.removeprefix("minecraft:") for w in e.get(attr, "").split())


def _maze_block(e: Optional[ET.Element]) -> Optional[MazeBlock]:
    if e is None:
        return None
    return MazeBlock(
        _words(e, "type"), _words(e, "colour"), _words(e, "variant"),
        int(e.get("height", "1")), int(e.get("heightVariance", "0")),
        e.get("fixedToEdge", "false").strip() in ("true", "1"),
    )  # fmt: skip


def maze(e: ET.Element, at: int) -> MazeSpec:
    """Read a ``<MazeDecorator>`` (``at``: drawing operations before it)."""
    k = _kids(e)
    size = k["SizeAndPosition"]
    gap = k["GapProbability"]
    way = k.get("Waypoints")
    way_kids = _kids(way) if way is not None else {}

    def block(name: str) -> MazeBlock:
        b = _maze_block(k.get(name))
        assert b is not None  # the schema requires it
        return b

    quit_e = k.get("AddQuitProducer")
    return MazeSpec(
        seed=_text(k["Seed"]),
        material_seed=_text(k["MaterialSeed"]) if "MaterialSeed" in k else None,
        allow_diagonal=_text(k.get("AllowDiagonalMovement"), "false") in ("true", "1"),
        width=int(size.get("width", "10")),
        length=int(size.get("length", "10")),
        height=int(size.get("height", "100")),
        scale=int(size.get("scale", "1")),
        origin=(
            int(size.get("xOrigin", "0")),
            int(size.get("yOrigin", "55")),
            int(size.get("zOrigin", "0")),
        ),  # fmt: skip
        start=block("StartBlock"),
        end=block("EndBlock"),
        path=block("PathBlock"),
        floor=block("FloorBlock"),
        gap=block("GapBlock"),
        optimal_path=_maze_block(k.get("OptimalPathBlock")),
        subgoal=_maze_block(k.get("SubgoalBlock")),
        waypoints=int(way.get("quantity", "0")) if way is not None else 0,
        waypoint_block=_maze_block(way_kids.get("WaypointBlock")),
        waypoint_item=_maze_block(way_kids.get("WaypointItem")),
        gap_probability=float(_text(gap, "0")),
        gap_variance=float(gap.get("variance", "0")),
        quit_description=quit_e.get("description", "") if quit_e is not None else None,
        navigation="AddNavigationObservations" in k,
        at=at,
    )


def classroom(e: ET.Element, at: int) -> ClassroomSpec:
    """Read a ``<ClassroomDecorator>`` (``at``: drawing operations before it)."""
    k = _kids(e)
    seed, palette = e.get("seed"), e.get("palette", "default").strip()
    if "complexity" in k:
        c = _kids(k["complexity"])
        values = tuple(float(_text(c[n])) for n in ("building", "path", "division", "obstacle",
                                                     "hint"))  # fmt: skip
        return ClassroomSpec(seed, palette, complexity=values, at=at)  # type: ignore[arg-type]
    s = _kids(k["specification"])

    def ints(name: str, fields: str) -> tuple[int, ...]:
        kids = _kids(s[name])
        return tuple(int(_text(kids[f])) for f in fields.split())

    return ClassroomSpec(
        seed, palette,
        size=(int(_text(s["width"])), int(_text(s["height"])), int(_text(s["length"]))),
        path_length=int(_text(s["pathLength"])),
        divisions=ints("divisions", "southNorth eastWest aboveBelow"),  # type: ignore[arg-type]
        horizontal=ints("horizontalObstacles", "gap bridge door puzzle jump"),  # type: ignore[arg-type]
        vertical=ints("verticalObstacles", "stairs ladder jump"),  # type: ignore[arg-type]
        hint_likelihood=float(_text(s["hintLikelihood"])),
        at=at,
    )  # fmt: skip


def build_battle(e: ET.Element) -> BuildBattleSpec:
    """Read a ``<BuildBattleDecorator>``."""
    k = _kids(e)

    def bounds(name: str) -> tuple[Cell, Cell]:
        lo, hi = (_kids(k[name])[c] for c in ("min", "max"))
        a = tuple(int(lo.get(v, "0")) for v in "xyz")
        b = tuple(int(hi.get(v, "0")) for v in "xyz")
        return a, b  # type: ignore[return-value]

    def mark(name: str) -> Optional[str]:
        m = k.get(name)
        return None if m is None else m.get("type", "").strip().removeprefix("minecraft:")

    return BuildBattleSpec(
        bounds("GoalStructureBounds"), bounds("PlayerStructureBounds"),
        mark("BlockTypeOnCorrectPlacement"), mark("BlockTypeOnIncorrectPlacement"),
    )  # fmt: skip
