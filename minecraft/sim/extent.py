"""How big a mission's world must be: Minecraft's worlds are unbounded, the simulator's
are boxes, so the box is sized to hold what the mission places.

A flat world spans the agent's placement, every block, item and entity the mission
draws (air is only cleared, never needs room), and every position marker, plus
``MARGIN`` blocks of ground around them; it is never smaller than 128×128 centred on the
origin, and as tall as its layers and drawings need, up to Minecraft's build height of
256. A seeded default world keeps its 128×128 terrain but is moved under a placement
that falls outside it (Malmo's ``defaultworld.xml`` starts the agent at x = -203.5,
z = 217.5). What a maze, classroom or build battle builds counts as placed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from minecraft.malmo.mission import Mission
from minecraft.sim import decorators

MARGIN = 32  # blocks of ground beyond the farthest thing the mission places
MIN_HALF = 64  # flat worlds span at least -64..63 in x and z
MAX_SIZE_XZ = 512  # a wider world is refused (memory: 512 * 256 * 512 bytes)
BUILD_HEIGHT = 256  # Minecraft 1.11's world height
HEADROOM = 8  # blocks of air above the highest thing placed


@dataclass(frozen=True)
class Box:
    """A world's block box: x in [x0, x0 + size_x), z likewise, y in [0, size_y)."""

    x0: int
    z0: int
    size_x: int
    size_z: int
    size_y: int


def anchors(mission: Mission) -> list[tuple[float, float, float]]:
    """Every point the world must contain: placement, drawn things, markers."""
    pts: list[tuple[float, float, float]] = []
    if mission.placement is not None:
        pts.append(mission.placement[:3])
    for op in mission.drawing:
        c = op.coords
        if op.kind in ("cuboid", "line"):
            if op.type != "air":
                pts += [(c[0], c[1], c[2]), (c[3], c[4], c[5])]
        elif op.kind == "sphere":
            if op.type != "air":
                r = c[3]
                pts += [(c[0] - r, c[1] - r, c[2] - r), (c[0] + r, c[1] + r, c[2] + r)]
        else:
            pts.append((c[0], c[1], c[2]))
    pts += decorators.footprint(mission)
    rules = mission.rules
    pts += [(m.x, m.y, m.z) for m in rules.positions]
    pts += [(m.x, m.y, m.z) for m in rules.quit_positions]
    return pts


def flat_box(
    mission: Mission, layers: int, also: tuple[tuple[float, float, float], ...] = ()
) -> Box:
    """The box of a flat world with ``layers`` ground layers, holding the points ``also``
    too (the other agents' placements).

    Raises:
        ValueError: the mission spans more than ``MAX_SIZE_XZ`` blocks.
    """
    pts = anchors(mission) + list(also)
    lo_x = min([-MIN_HALF] + [math.floor(p[0]) - MARGIN for p in pts])
    hi_x = max([MIN_HALF] + [math.floor(p[0]) + 1 + MARGIN for p in pts])
    lo_z = min([-MIN_HALF] + [math.floor(p[2]) - MARGIN for p in pts])
    hi_z = max([MIN_HALF] + [math.floor(p[2]) + 1 + MARGIN for p in pts])
    if hi_x - lo_x > MAX_SIZE_XZ or hi_z - lo_z > MAX_SIZE_XZ:
        raise ValueError(
            f"the mission places things {hi_x - lo_x - 2 * MARGIN} x {hi_z - lo_z - 2 * MARGIN} "
            f"blocks apart; the simulator's worlds are at most {MAX_SIZE_XZ - 2 * MARGIN} wide"
        )
    return Box(lo_x, lo_z, hi_x - lo_x, hi_z - lo_z, height(mission, layers, also=also))


def height(
    mission: Mission, ground: int, minimum: int = 64,
    also: tuple[tuple[float, float, float], ...] = (),
) -> int:  # fmt: skip
    """World height: the ground, everything placed (and ``also``) and some air above, at
    most 256."""
    top = max([ground] + [math.floor(p[1]) + 1 for p in anchors(mission) + list(also)])
    return min(BUILD_HEIGHT, max(minimum, top + HEADROOM))


def check(mission: Mission) -> None:
    """Raise ValueError naming the problem when the mission's world cannot be built."""
    if mission.flat_generator is not None:
        flat_box(mission, 0)
