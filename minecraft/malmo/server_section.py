"""Malmo's schema (``Mission.xsd`` 0.37) for a ``<ServerSection>``'s handlers, as
``xsd_elements`` rules: the world generators, the decorators (``DrawingDecorator``'s draw
operations, ``MazeDecorator``, ``ClassroomDecorator`` and ``BuildBattleDecorator`` in
full; the content of the ones the simulator does not implement, such as
``SnakeDecorator``, is not checked) and the server quit producers.
"""

from __future__ import annotations

import re
from typing import Optional

from minecraft import names as N
from minecraft.malmo.xsd_elements import (
    ANY,
    DESC,
    EMPTY,
    INT_POS,
    Rule,
    all_of,
    el,
    many,
    one,
    seq,
    text,
)
from minecraft.malmo.xsd_types import (
    BLOCK,
    BLOCK_LIST,
    BLOCK_OR_ITEM,
    BLOCK_OR_ITEM_LIST,
    BOOL,
    COLOUR,
    COLOUR_LIST,
    DECIMAL,
    FACING,
    INT,
    STRING,
    VARIANT,
    VARIANT_LIST,
    Check,
    decimal_range,
    int_range,
    one_of,
)

_BLOCK_BASED = {"type": BLOCK, "variant": VARIANT, "colour": COLOUR, "face": FACING}
_CORNERS = {k: INT for k in ("x1", "y1", "z1", "x2", "y2", "z2")}
DRAW_OPS: dict[str, Rule] = {
    "DrawObjectType": EMPTY,
    "DrawBlock": el(_BLOCK_BASED | INT_POS, "type x y z"),
    "DrawCuboid": el(_BLOCK_BASED | _CORNERS, "type x1 y1 z1 x2 y2 z2"),
    "DrawSphere": el(_BLOCK_BASED | INT_POS | {"radius": INT}, "type x y z radius"),
    "DrawLine": el(_BLOCK_BASED | _CORNERS | {"steptype": BLOCK}, "type x1 y1 z1 x2 y2 z2"),
    "DrawItem": el(_BLOCK_BASED | INT_POS | {"type": BLOCK_OR_ITEM}, "type x y z"),
    "DrawEntity": el(
        {
            "x": DECIMAL,
            "y": DECIMAL,
            "z": DECIMAL,
            "yaw": DECIMAL,
            "pitch": DECIMAL,
            "xVel": DECIMAL,
            "yVel": DECIMAL,
            "zVel": DECIMAL,
            "type": one_of(N.SPAWNABLE_TYPES, "a spawnable entity type"),
        },
        "type x y z",
    ),  # fmt: skip
    "DrawContainer": seq(
        many(
            {
                "Object": el(
                    {"type": BLOCK_OR_ITEM, "variant": VARIANT, "colour": COLOUR, "quantity": INT},
                    "type",
                )
            }
        ),
        attrs=_BLOCK_BASED | INT_POS | {"type": one_of(N.CONTAINER_TYPES, "a container type")},
        req="type x y z",
    ),  # fmt: skip
    "DrawSign": el(
        _BLOCK_BASED
        | INT_POS
        | {"type": one_of(N.SIGN_TYPES, "a sign type"), "rotation": INT}
        | {f"line{i}": STRING for i in range(1, 5)},
        "type x y z",
    ),  # fmt: skip
}
_RESET = {"forceReset": BOOL, "destroyAfterUse": BOOL}
GENERATORS: dict[str, Rule] = {
    "FlatWorldGenerator": el({"generatorString": STRING, "seed": STRING} | _RESET),
    "FileWorldGenerator": el({"src": STRING} | _RESET, "src"),
    "DefaultWorldGenerator": el({"seed": STRING, "generatorOptions": STRING} | _RESET),
    "BiomeGenerator": el({"biome": INT} | _RESET),
}


def _seed(v: str) -> Optional[str]:
    return None if re.fullmatch(r"random|[0-9]+", v.strip()) else "is not an integer or 'random'"


_MAZE_BLOCK = {"type": BLOCK_LIST, "variant": VARIANT_LIST, "colour": COLOUR_LIST,
               "height": INT, "heightVariance": INT}  # fmt: skip
_TERMINUS = el(_MAZE_BLOCK | {"fixedToEdge": BOOL})
MAZE = all_of(
    {
        "Seed": text(_seed),
        "MaterialSeed": text(_seed),
        "AllowDiagonalMovement": text(BOOL),
        "SizeAndPosition": el({k: INT for k in ("width", "length", "height", "scale",
                                                "xOrigin", "yOrigin", "zOrigin")}),
        "StartBlock": _TERMINUS,
        "EndBlock": _TERMINUS,
        "PathBlock": el(_MAZE_BLOCK),
        "FloorBlock": el(_MAZE_BLOCK),
        "GapBlock": el(_MAZE_BLOCK),
        "OptimalPathBlock": el(_MAZE_BLOCK),
        "SubgoalBlock": el(_MAZE_BLOCK),
        "Waypoints": seq(
            ({"WaypointBlock": el(_MAZE_BLOCK),
              "WaypointItem": el({"type": BLOCK_OR_ITEM_LIST, "amount": INT,
                                  "variant": VARIANT_LIST, "colour": COLOUR_LIST}, "type")},
             1, 1),
            attrs={"quantity": INT}, req="quantity",
        ),
        "GapProbability": Rule({"variance": DECIMAL}, kind="text", text=DECIMAL),
        "AddQuitProducer": el(DESC),
        "AddNavigationObservations": EMPTY,
    },
    "Seed SizeAndPosition StartBlock EndBlock PathBlock FloorBlock GapBlock GapProbability",
)  # fmt: skip


def _counts(names: str) -> Rule:
    return all_of({n: text(_NON_NEGATIVE) for n in names.split()}, names)


_NON_NEGATIVE: Check = int_range(0)
_ZERO_TO_ONE: Check = decimal_range(0, 1)
_SIZE = text(int_range(7, 50))
CLASSROOM = seq(
    (
        {
            "complexity": seq(*(one(n, text(_ZERO_TO_ONE))
                                for n in ("building", "path", "division", "obstacle", "hint"))),
            "specification": seq(
                one("width", _SIZE), one("height", _SIZE), one("length", _SIZE),
                one("pathLength", text(_NON_NEGATIVE)),
                one("divisions", _counts("southNorth eastWest aboveBelow")),
                one("horizontalObstacles", _counts("gap bridge door puzzle jump")),
                one("verticalObstacles", _counts("stairs ladder jump")),
                one("hintLikelihood", text(_ZERO_TO_ONE)),
            ),
        },
        1,
        1,
    ),
    attrs={"seed": STRING,
           "palette": one_of(("default", "random", "dungeon", "pyramid", "igloo"), "a palette")},
)  # fmt: skip
_BOUNDS = seq(one("min", el(INT_POS, "x y z")), one("max", el(INT_POS, "x y z")))
BUILD_BATTLE = all_of(
    {
        "GoalStructureBounds": _BOUNDS,
        "PlayerStructureBounds": _BOUNDS,
        "BlockTypeOnCorrectPlacement": el(_BLOCK_BASED, "type"),
        "BlockTypeOnIncorrectPlacement": el(_BLOCK_BASED, "type"),
    },
    "GoalStructureBounds PlayerStructureBounds",
)
DECORATORS: dict[str, Rule] = {
    "DrawingDecorator": seq(many(DRAW_OPS)),
    "MazeDecorator": MAZE,
    "ClassroomDecorator": CLASSROOM,
    "BuildBattleDecorator": BUILD_BATTLE,
} | {
    name: ANY
    for name in (
        "AnimationDecorator", "SnakeDecorator", "MovingTargetDecorator", "NavigationDecorator",
    )
}  # fmt: skip
SERVER_QUITS: dict[str, Rule] = {
    "ServerQuitFromTimeUp": el({"timeLimitMs": DECIMAL} | DESC, "timeLimitMs"),
    "ServerQuitWhenAnyAgentFinishes": el(DESC),
}
SERVER_HANDLERS: dict[str, Rule] = GENERATORS | DECORATORS | SERVER_QUITS
