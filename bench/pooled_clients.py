"""Real-time Minecraft clients for the clients sweep of ``minecraft.py``: one actor's
environments on consecutive world servers of a pool, and the per-block grid encoding the
vectorised one replaced (the baseline measured in the same run).

Ray workers import this module through the env spec's ``import_path`` (this folder).
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np

from minecraft import blocks as B
from minecraft.agent import grid_encoding
from minecraft.agent.mission_env import ENV_ID

VECTORISED_ENCODE = grid_encoding.encode
_made = itertools.count()  # environments this process made: the next one takes the next world
_FULL: dict[str, float] = {name: float(B.SOLID[i]) for i, name in enumerate(B.NAMES)}


def encode_per_block(
    info: Mapping[str, Any], *, k: int = 8, grid: str = "cube", entities: str = "entities"
) -> np.ndarray:
    """`grid_encoding.encode` as it was before the block-id table: the cube through a
    Python generator, block by block (unchanged otherwise)."""
    G = grid_encoding
    x, y, z = float(info["XPos"]), float(info["YPos"]), float(info["ZPos"])
    yaw = math.radians(float(info["Yaw"]))
    stats = np.array(
        [x / G.POSITION_SCALE, y / G.POSITION_SCALE, z / G.POSITION_SCALE, math.sin(yaw),
         math.cos(yaw), float(info["Pitch"]) / 90.0, float(info.get("Life", 20.0)) / 20.0,
         float(info.get("Food", 20)) / 20.0],
        dtype=np.float32,
    )  # fmt: skip
    cube = np.fromiter(
        (_FULL.get(n, 0.0 if n == "air" else 1.0) for n in info[grid]), dtype=np.float32
    )
    items = np.zeros((k, G.ITEM_FIELDS), dtype=np.float32)
    found = [
        (e["x"] - x, e["y"] - y, e["z"] - z) for e in info.get(entities, ()) if "quantity" in e
    ]
    found.sort(key=lambda d: d[0] ** 2 + d[1] ** 2 + d[2] ** 2)
    for i, (dx, dy, dz) in enumerate(found[:k]):
        items[i] = (dx / G.ITEM_SCALE, dy / G.ITEM_SCALE, dz / G.ITEM_SCALE, 1.0)
    return np.concatenate([stats, cube, items.reshape(-1)])


def pooled_mission(
    *,
    addresses: list[str],
    mission_xml: str,
    world_seed: int,
    max_episode_steps: int,
    per_block_encoding: bool = False,
) -> gym.Env:
    """The next of `addresses`' mission environments (each call in this process takes the
    next world); `per_block_encoding` decodes and encodes observations the old way."""
    grid_encoding.encode = encode_per_block if per_block_encoding else VECTORISED_ENCODE  # type: ignore[assignment]
    i = next(_made)
    env = gym.make(
        ENV_ID,
        address=addresses[i % len(addresses)],
        mission_xml=mission_xml,
        world_seed=world_seed + i,
        max_episode_steps=max_episode_steps,
    )
    if per_block_encoding:  # and the whole info JSON decoded every tick, as before
        env.unwrapped.client.info_decoder = json.loads  # type: ignore[attr-defined]
    return env


def actors_for(clients: int, per_actor: int) -> list[range]:
    """Which clients each actor drives (the last actor may drive fewer)."""
    return [range(a * per_actor, min(clients, (a + 1) * per_actor))
            for a in range(math.ceil(clients / per_actor))]  # fmt: skip
