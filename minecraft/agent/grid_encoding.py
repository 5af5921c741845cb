"""The observation vector of the paper's sec. III-D: position and orientation, the
15×15×15 occupancy cube as {0, 1}, and the k closest items by their coordinates.

Layout (float32, ``size(k) = 8 + 3375 + 4k``; offsets for the default cube)::

    [0:3]      x / 64, y / 64, z / 64          ObservationFromFullStats XPos, YPos, ZPos
    [3:6]      sin(yaw), cos(yaw), pitch / 90   Yaw (degrees, 0 = +z), Pitch (> 0 looks down)
    [6:8]      life / 20, food / 20             Life, Food
    [8:3383]   cube occupancy, Malmo's order    1 = full (any solid block), 0 = empty
               cell (dx, dy, dz) in -7..7 is at 8 + (dy+7)*225 + (dz+7)*15 + (dx+7)
    [3383:]    k items, nearest first, 4 each:  (ix - x) / 16, (iy - y) / 16,
               (iz - z) / 16, present           present = 1; absent items are all 0

No distinction is made between block types (the paper: "0 means empty block and 1 means
full block"); liquids, air and torches are empty. Names a real Minecraft has and the
simulator does not count as full unless they are air. Items are the dropped-item
entities of ObservationFromNearbyEntities (they carry ``quantity``), by Euclidean
distance from the agent; animals are not items.

This module is the single source of the encoding: the mission environment's
``minecraft.agent.mission_env.encode_observation`` delegates here.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from minecraft import blocks as B

STATS = ("x", "y", "z", "sin_yaw", "cos_yaw", "pitch", "life", "food")
CUBE_RADIUS = 7
CUBE_SIDE = 2 * CUBE_RADIUS + 1
CUBE_CELLS = CUBE_SIDE**3
ITEM_FIELDS = 4
POSITION_SCALE = 64.0
ITEM_SCALE = 16.0  # the mission's entity range


class _BlockIds(dict[str, int]):
    """Block name -> id: the simulator's ids (``blocks.ID``) for the names it knows, and
    one more for any other name (``UNKNOWN_FULL``): a real Minecraft's blocks the
    simulator lacks count as full."""

    def __missing__(self, name: str) -> int:
        return UNKNOWN_FULL


BLOCK_IDS = _BlockIds(B.ID)
"""Block name -> id, the table the grid's names are looked up in."""
UNKNOWN_FULL = len(B.NAMES)
"""The id of a block name the table does not know (a full block)."""
FULL_BY_ID = np.append(B.SOLID.astype(np.float32), np.float32(1.0))
"""Block id -> occupancy (1 = full): the solid blocks, and unknown names."""


def size(k: int, cube_cells: int = CUBE_CELLS) -> int:
    """Length of the vector with ``k`` items."""
    return len(STATS) + cube_cells + ITEM_FIELDS * k


def cube_offset(dx: int, dy: int, dz: int) -> int:
    """Index in the vector of the cube cell at (dx, dy, dz) from the agent's block."""
    r, s = CUBE_RADIUS, CUBE_SIDE
    return len(STATS) + (dy + r) * s * s + (dz + r) * s + (dx + r)


def items_offset(cube_cells: int = CUBE_CELLS) -> int:
    """Index of the first item field."""
    return len(STATS) + cube_cells


def block_ids(names: Sequence[str]) -> np.ndarray:
    """The grid's block names as ids (int16), looked up in C: ``map`` over the table's
    ``__getitem__`` runs no Python bytecode per block (unknown names: ``UNKNOWN_FULL``)."""
    return np.fromiter(map(BLOCK_IDS.__getitem__, names), dtype=np.int16, count=len(names))


class GridInfo:
    """Decodes a step's info JSON (bytes) with the grid ``grid`` as block ids (int16)
    instead of names, for ``encode``; a ``MalmoClient``'s ``info_decoder``.

    A real-time client gets an observation every tick, and the 15×15×15 grid's text is
    most of it (about 24 kB of names), yet it changes only when the agent enters another
    block or a block nearby changes. So the grid's text is cut out of the JSON, compared
    with the last one, and decoded only when it differs; the rest (under 1 kB) is
    decoded every time. Malmo writes the grid as a flat array of block names, which hold
    no ``]``; JSON without the grid is decoded whole.
    """

    def __init__(self, grid: str) -> None:
        self.grid = grid
        self._key = b'"' + grid.encode() + b'":['
        self._text = b""
        self._ids = np.zeros(0, dtype=np.int16)

    def __call__(self, raw: bytes) -> dict[str, Any]:
        i = raw.find(self._key)
        end = raw.find(b"]", i) if i >= 0 else -1
        if end < 0:
            whole: dict[str, Any] = json.loads(raw) if raw else {}
            return whole
        text = raw[i + len(self._key) - 1 : end + 1]
        if text != self._text:
            ids = block_ids(json.loads(text))
            ids.flags.writeable = False  # shared by every info decoded from the same text
            self._text, self._ids = text, ids
        # Drop `"grid":[...]` and the comma that joined it to its neighbour.
        before, after = raw[:i], raw[end + 1 :]
        if after.startswith(b","):
            after = after[1:]
        elif before.endswith(b","):
            before = before[:-1]
        info: dict[str, Any] = json.loads(before + after)
        info[self.grid] = self._ids
        return info


def encode(
    info: Mapping[str, Any], *, k: int = 8, grid: str = "cube", entities: str = "entities"
) -> np.ndarray:
    """One step's decoded info JSON -> the float32 vector described above.

    Args:
        info: merged observation producers (full stats, the grid's block names or
            their ids from ``GridInfo``, nearby entities).
        k: number of item slots.
        grid: name of the ObservationFromGrid grid.
        entities: name of the ObservationFromNearbyEntities range.

    Raises:
        KeyError: a stat or the grid is missing from ``info``.
    """
    x, y, z = float(info["XPos"]), float(info["YPos"]), float(info["ZPos"])
    yaw = math.radians(float(info["Yaw"]))
    stats = np.array(
        [
            x / POSITION_SCALE,
            y / POSITION_SCALE,
            z / POSITION_SCALE,
            math.sin(yaw),
            math.cos(yaw),
            float(info["Pitch"]) / 90.0,
            float(info.get("Life", 20.0)) / 20.0,
            float(info.get("Food", 20)) / 20.0,
        ],
        dtype=np.float32,
    )
    names = info[grid]  # or their ids, as GridInfo decodes them
    cube = FULL_BY_ID[names if isinstance(names, np.ndarray) else block_ids(names)]
    items = np.zeros((k, ITEM_FIELDS), dtype=np.float32)
    found = [
        (e["x"] - x, e["y"] - y, e["z"] - z)
        for e in info.get(entities, ())
        if "quantity" in e  # dropped items (animals and the agent have no quantity)
    ]
    found.sort(key=lambda d: d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
    for i, (dx, dy, dz) in enumerate(found[:k]):
        items[i] = (dx / ITEM_SCALE, dy / ITEM_SCALE, dz / ITEM_SCALE, 1.0)
    return np.concatenate([stats, cube, items.reshape(-1)])
