"""Vectors in and out of a MalmoEnv agent: the Ray actor's observation encoding and its
continuous actions.

Observations are encoded by ``obs_encoding.encode`` (the paper's sec. III-D vector:
position, orientation, life and food, the grid as ``{0,1}`` occupancy, then ``k``
nearest items; the layout is documented there). The actor uses ``k = 0`` unless told
otherwise; this module fixes the vector's size from the mission and checks each grid.

The action is a box ``[-1, 1]^6``: move, strafe, turn, pitch (ContinuousMovementCommands
speeds), then jump and attack, which are on when their component is positive.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from actors.minecraft.agent import grid_encoding as obs_encoding
from actors.minecraft.malmo.mission import Mission

ACTION_NAMES = ("move", "strafe", "turn", "pitch", "jump", "attack")
ACTION_SPACE = spaces.Box(-1.0, 1.0, shape=(len(ACTION_NAMES),), dtype=np.float32)


def _cells(mission: Mission) -> int:
    (g,) = mission.grids
    return math.prod(h - lo + 1 for lo, h in zip(g.lo, g.hi, strict=True))


def observation_space(mission: Mission, k: int = 0) -> spaces.Box:
    """The encoded observation's space for ``mission`` with ``k`` item slots.

    Raises:
        ValueError: the mission lacks ObservationFromFullStats or has not exactly one
            ObservationFromGrid grid, which the encoding reads.
    """
    if not mission.full_stats:
        raise ValueError(
            "the mission has no <ObservationFromFullStats/>: the encoding needs position, "
            "orientation, life, food and TotalTime (to count skipped ticks)"
        )
    if len(mission.grids) != 1:
        raise ValueError(
            f"the mission has {len(mission.grids)} ObservationFromGrid grids; the encoding "
            "reads exactly one (the cube around the agent): add one <Grid> or merge them"
        )
    size = obs_encoding.size(k, _cells(mission))
    return spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)


def encode_observation(info: Mapping[str, Any], mission: Mission, k: int = 0) -> np.ndarray:
    """One step's info JSON (already decoded) -> the float32 observation vector.

    Args:
        info: the merged observation producers of one step.
        mission: the mission the info comes from (names the grid and entity range).
        k: nearest dropped items to include (``obs_encoding``'s item slots).

    Returns:
        A vector of ``observation_space(mission, k).shape``.

    Raises:
        KeyError: a stat or the grid is missing from ``info``.
        ValueError: the grid has the wrong number of cells.
    """
    grid = mission.grids[0].name
    cells = _cells(mission)
    if len(info[grid]) != cells:
        raise ValueError(f"grid {grid!r} has {len(info[grid])} cells, the mission says {cells}")
    entities = mission.nearby[0].name if mission.nearby else "entities"
    return obs_encoding.encode(info, k=k, grid=grid, entities=entities)


def action_commands(action: np.ndarray) -> str:
    """A (possibly unclipped) action -> newline-joined ContinuousMovementCommands.

    The action is clipped into ``[-1, 1]`` here, as an environment clips it; the actor
    stores the unclipped one.
    """
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    return (
        f"move {a[0]:.3f}\nstrafe {a[1]:.3f}\nturn {a[2]:.3f}\npitch {a[3]:.3f}\n"
        f"jump {int(a[4] > 0)}\nattack {int(a[5] > 0)}"
    )
