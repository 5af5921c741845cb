"""Malmo's schema (``Mission.xsd`` 0.37) for a ``<ServerSection>``'s handlers, as
``xsd_elements`` rules: the world generators, the decorators (``DrawingDecorator``'s draw
operations in full; the content of the ones the simulator does not implement, such as
``MazeDecorator``, is not checked) and the server quit producers.
"""

from __future__ import annotations

from actors.minecraft import names as N
from actors.minecraft.malmo.xsd_elements import ANY, DESC, EMPTY, INT_POS, Rule, el, many, seq
from actors.minecraft.malmo.xsd_types import (
    BLOCK,
    BLOCK_OR_ITEM,
    BOOL,
    COLOUR,
    DECIMAL,
    FACING,
    INT,
    STRING,
    VARIANT,
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
    "DefaultWorldGenerator": el({"seed": STRING} | _RESET),
    "BiomeGenerator": el({"biome": INT} | _RESET),
}
DECORATORS: dict[str, Rule] = {"DrawingDecorator": seq(many(DRAW_OPS))} | {
    name: ANY
    for name in (
        "AnimationDecorator", "MazeDecorator", "ClassroomDecorator", "SnakeDecorator",
        "MovingTargetDecorator", "BuildBattleDecorator", "NavigationDecorator",
    )
}  # fmt: skip
SERVER_QUITS: dict[str, Rule] = {
    "ServerQuitFromTimeUp": el({"timeLimitMs": DECIMAL} | DESC, "timeLimitMs"),
    "ServerQuitWhenAnyAgentFinishes": el(DESC),
}
SERVER_HANDLERS: dict[str, Rule] = GENERATORS | DECORATORS | SERVER_QUITS
