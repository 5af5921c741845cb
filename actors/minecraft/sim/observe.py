"""Malmo observation producers: the JSON "info" string a step returns.

Formats follow Malmo's producers: ObservationFromFullStats keys (distances in
centimetres and damage in tenths, as Minecraft's statistics count them),
ObservationFromGrid lists of block names ordered x fastest, then z, then y (relative to
the block the agent stands in), ObservationFromFullInventory (flat ``InventorySlot_i_*``
keys or a list), ObservationFromNearbyEntities and ObservationFromRay (``LineOfSight``).
Grids are cut from the voxel array by slicing, never by per-block loops.
"""

from __future__ import annotations

import json
import math

import numpy as np

from actors.minecraft import blocks as B
from actors.minecraft.malmo.mission import Grid
from actors.minecraft.sim import interact
from actors.minecraft.sim.inventory import N_SLOTS
from actors.minecraft.sim.raycast import REACH
from actors.minecraft.sim.world import World

RAY_RANGE = 20.0


def grid_ids(world: World, grid: Grid) -> np.ndarray:
    """Block ids of a grid as a (y, z, x) array relative to the agent's block."""
    b = world.player.body
    px, py, pz = math.floor(b.x), math.floor(b.y), math.floor(b.z)
    lo = (px + grid.lo[0] - world.x0, py + grid.lo[1], pz + grid.lo[2] - world.z0)
    hi = (px + grid.hi[0] - world.x0 + 1, py + grid.hi[1] + 1, pz + grid.hi[2] - world.z0 + 1)
    sx, sy, sz = world.blocks.shape
    if lo[0] >= 0 and lo[1] >= 0 and lo[2] >= 0 and hi[0] <= sx and hi[1] <= sy and hi[2] <= sz:
        sub = world.blocks[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    else:
        shape = (hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
        sub = np.full(shape, B.BEDROCK, dtype=np.uint8)
        ys = np.arange(lo[1], hi[1])
        sub[:, ys >= sy, :] = B.AIR
        a = [max(lo[0], 0), max(lo[1], 0), max(lo[2], 0)]
        e = [min(hi[0], sx), min(hi[1], sy), min(hi[2], sz)]
        if all(x < y for x, y in zip(a, e, strict=True)):
            dst = tuple(slice(a[i] - lo[i], e[i] - lo[i]) for i in range(3))
            sub[dst] = world.blocks[a[0] : e[0], a[1] : e[1], a[2] : e[2]]
    return sub.transpose(1, 2, 0)


def full_stats(world: World) -> dict[str, object]:
    """ObservationFromFullStats."""
    p, b = world.player, world.player.body
    return {
        "DistanceTravelled": int(p.distance * 100),
        "TimeAlive": p.time_alive,
        "MobsKilled": p.mobs_killed,
        "PlayersKilled": 0,
        "DamageTaken": int(p.damage_taken * 10),
        "DamageDealt": int(p.damage_dealt * 10),
        "Life": float(p.health),
        "Score": 0,
        "Food": p.food,
        "XP": p.xp,
        "IsAlive": p.alive,
        "Air": p.air,
        "Name": p.name,
        "XPos": b.x,
        "YPos": b.y,
        "ZPos": b.z,
        "Pitch": p.pitch,
        "Yaw": p.yaw,
        "WorldTime": world.world_time,
        "TotalTime": world.tick_count,
    }


def inventory(world: World, flat: bool) -> dict[str, object]:
    """ObservationFromFullInventory (``flat`` as Malmo's attribute)."""
    inv = world.player.inventory
    out: dict[str, object] = {}
    if flat:
        for i in range(N_SLOTS):
            s = inv.slots[i]
            out[f"InventorySlot_{i}_size"] = s.count if s is not None else 0
            out[f"InventorySlot_{i}_item"] = s.item if s is not None else "air"
    else:
        out["inventory"] = [
            {"type": s.item, "index": i, "quantity": s.count, "inventory": "inventory"}
            for i, s in enumerate(inv.slots)
            if s is not None
        ]
        out["inventoriesAvailable"] = [{"name": "inventory", "size": N_SLOTS}]
    out["currentItemIndex"] = inv.selected
    return out


def nearby(world: World, xr: float, yr: float, zr: float) -> list[dict[str, object]]:
    """Entities within a box around the agent (the agent itself first, as in Malmo)."""
    p, b = world.player, world.player.body
    out: list[dict[str, object]] = [
        {"yaw": p.yaw, "x": b.x, "y": b.y, "z": b.z, "pitch": p.pitch, "id": "agent",
         "motionX": b.vx, "motionY": b.vy, "motionZ": b.vz, "life": p.health, "name": p.name}
    ]  # fmt: skip
    for m in world.mobs:
        mb = m.body
        if abs(mb.x - b.x) <= xr and abs(mb.y - b.y) <= yr and abs(mb.z - b.z) <= zr:
            out.append(
                {"yaw": m.yaw, "x": mb.x, "y": mb.y, "z": mb.z, "pitch": 0.0, "id": str(m.uid),
                 "motionX": mb.vx, "motionY": mb.vy, "motionZ": mb.vz, "life": m.health,
                 "name": m.name}
            )  # fmt: skip
    for it in world.items:
        ib = it.body
        if abs(ib.x - b.x) <= xr and abs(ib.y - b.y) <= yr and abs(ib.z - b.z) <= zr:
            out.append(
                {"yaw": 0.0, "x": ib.x, "y": ib.y, "z": ib.z, "pitch": 0.0, "id": str(it.uid),
                 "motionX": ib.vx, "motionY": ib.vy, "motionZ": ib.vz, "name": it.item,
                 "quantity": it.count}
            )  # fmt: skip
    return out


def line_of_sight(world: World) -> dict[str, object]:
    """ObservationFromRay: what the crosshair points at within 20 blocks."""
    hit = interact.target(world, RAY_RANGE)
    if hit is None:
        return {}
    d: dict[str, object] = {
        "hitType": hit.kind,
        "x": hit.x,
        "y": hit.y,
        "z": hit.z,
        "distance": hit.distance,
        "inRange": hit.distance <= REACH,
    }
    if hit.kind == "block":
        d["type"] = B.NAMES[world.get(*hit.cell)]
        d["blockX"], d["blockY"], d["blockZ"] = hit.cell
    else:
        m = world.mobs[hit.entity]
        d["type"] = m.name
        d["life"] = m.health
    return d


def info_json(world: World) -> str:
    """All of the mission's observations as one JSON object string."""
    m = world.mission
    obs: dict[str, object] = {}
    if m.full_stats:
        obs.update(full_stats(world))
    if m.full_inventory:
        obs.update(inventory(world, m.inventory_flat))
    for r in m.nearby:
        obs[r.name] = nearby(world, r.x, r.y, r.z)
    if m.ray:
        los = line_of_sight(world)
        if los:
            obs["LineOfSight"] = los
    text = json.dumps(obs, separators=(",", ":"))
    if not m.grids:
        return text
    b = world.player.body
    key = (world.version, math.floor(b.x), math.floor(b.y), math.floor(b.z))
    cache = world.obs_cache
    if cache.get("grid_key") != key:
        cache["grid_key"] = key
        cache["grid"] = ",".join(
            f'"{g.name}":[' + ",".join(B.QUOTED[grid_ids(world, g).ravel()].tolist()) + "]"
            for g in m.grids
        )
    grids = str(cache["grid"])
    return "{" + grids + ("," + text[1:] if len(text) > 2 else "}")
