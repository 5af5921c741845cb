"""Malmo observation producers: the JSON "info" string a step returns.

Formats follow Malmo's producers: ObservationFromFullStats keys (distances in
centimetres and damage in tenths, as Minecraft's statistics count them; ``Yaw`` is not
wrapped), ObservationFromGrid lists of block names ordered x fastest, then z, then y
(relative to the block the agent stands in, or in world coordinates with
``absoluteCoords``), ObservationFromFullInventory (flat ``InventorySlot_i_*`` keys or a
list), ObservationFromHotBar (``Hotbar_i_*``), ObservationFromNearbyEntities (UUID ids,
strictly inside the range), ObservationFromRay (``LineOfSight``: the first block, animal
or item within 50 blocks), ObservationFromDistance (``distanceFrom<name>``),
ObservationFromRecentCommands (``CommandsSinceLastObservation``) and
ObservationFromChat (``Chat``). Grids are cut from the voxel array by slicing, never by
per-block loops.
"""

from __future__ import annotations

import json
import math

import numpy as np

from minecraft import blocks as B
from minecraft.malmo.mission import Grid
from minecraft.sim import interact
from minecraft.sim.inventory import N_SLOTS
from minecraft.sim.raycast import REACH
from minecraft.sim.world import World

RAY_RANGE = 50.0  # Malmo's ObservationFromRay depth
ENTITY_REACH = 3.0  # the ray's inRange for animals and items (survival)


def grid_ids(world: World, grid: Grid) -> np.ndarray:
    """Block ids of a grid as a (y, z, x) array, relative to the agent's block unless the
    grid is absolute."""
    b = world.player.body
    px, py, pz = math.floor(b.x), math.floor(b.y), math.floor(b.z)
    if grid.absolute:
        px = py = pz = 0
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
        out.update(_slots(world, "InventorySlot_", N_SLOTS))
    else:
        out["inventory"] = [
            {"type": s.item, "index": i, "quantity": s.count, "inventory": "inventory"}
            for i, s in enumerate(inv.slots)
            if s is not None
        ]
    out["inventoriesAvailable"] = [{"name": "inventory", "size": N_SLOTS}]
    out["currentItemIndex"] = inv.selected
    return out


def _slots(world: World, prefix: str, n: int) -> dict[str, object]:
    out: dict[str, object] = {}
    for i, s in enumerate(world.player.inventory.slots[:n]):
        out[f"{prefix}{i}_size"] = s.count if s is not None else 0
        out[f"{prefix}{i}_item"] = s.item if s is not None else "air"
    return out


def nearby(world: World, xr: float, yr: float, zr: float) -> list[dict[str, object]]:
    """Entities strictly inside a box around the agent: the agent itself first, then the
    mission's other agents, animals and items."""
    p, b = world.player, world.player.body

    def near(e: object) -> bool:
        return abs(e.x - b.x) < xr and abs(e.y - b.y) < yr and abs(e.z - b.z) < zr  # type: ignore[attr-defined]

    out: list[dict[str, object]] = [
        {"yaw": p.yaw, "x": b.x, "y": b.y, "z": b.z, "pitch": p.pitch,
         "id": world.entity_uuid(world.player_uid), "motionX": b.vx, "motionY": b.vy,
         "motionZ": b.vz, "life": p.health, "name": p.name}
    ]  # fmt: skip
    for w in world.agents:  # the other agents of the mission, as Malmo lists players
        o, ob = w.player, w.player.body
        if w is not world and near(ob):
            out.append(
                {"yaw": o.yaw, "x": ob.x, "y": ob.y, "z": ob.z, "pitch": o.pitch,
                 "id": world.entity_uuid(w.player_uid), "motionX": ob.vx, "motionY": ob.vy,
                 "motionZ": ob.vz, "life": o.health, "name": o.name}
            )  # fmt: skip
    for m in world.mobs:
        mb = m.body
        if near(mb):
            out.append(
                {"yaw": m.yaw, "x": mb.x, "y": mb.y, "z": mb.z, "pitch": 0.0,
                 "id": world.entity_uuid(m.uid), "motionX": mb.vx, "motionY": mb.vy,
                 "motionZ": mb.vz, "life": m.health, "name": m.name}
            )  # fmt: skip
    for it in world.items:
        ib = it.body
        if near(ib):
            out.append(
                {"yaw": 0.0, "x": ib.x, "y": ib.y, "z": ib.z, "pitch": 0.0,
                 "id": world.entity_uuid(it.uid), "motionX": ib.vx, "motionY": ib.vy,
                 "motionZ": ib.vz, "quantity": it.count, "name": it.item}
            )  # fmt: skip
    return out


def line_of_sight(world: World) -> dict[str, object]:
    """ObservationFromRay: the first block, animal or item on the crosshair's ray within
    50 blocks (liquids are looked through), in Malmo's fields."""
    hit = interact.target(world, RAY_RANGE, items=True)
    if hit is None:
        return {}
    if hit.kind == "block":
        return {"hitType": "block", "x": hit.x, "y": hit.y, "z": hit.z,
                "type": B.NAMES[world.get(*hit.cell)], "inRange": hit.distance <= REACH,
                "distance": hit.distance}  # fmt: skip
    if hit.kind == "item":
        it = world.items[hit.entity]
        e, name, kind = it.body, it.item, "item"
        extra: dict[str, object] = {"stackSize": it.count}
        yaw = 0.0
    else:
        m = world.mobs[hit.entity]
        e, name, kind, extra, yaw = m.body, m.name, "entity", {}, m.yaw
    return {"x": e.x, "y": e.y, "z": e.z, "yaw": yaw, "pitch": 0.0, **extra, "type": name,
            "hitType": kind, "inRange": hit.distance <= ENTITY_REACH,
            "distance": hit.distance}  # fmt: skip


def next_subgoal(world: World) -> dict[str, object]:
    """ObservationFromSubgoalPositionList: the points passed so far are skipped (within a
    point's tolerance, x and z distances added), then ``yawDelta`` (the turn towards the
    next, in [-1, 1] of 180 degrees) and ``nextSubgoal``; nothing once all are passed."""
    points, b = world.mission.subgoals, world.player.body
    while world.subgoal_index < len(points):
        p = points[world.subgoal_index]
        if abs(p.x - b.x) + abs(p.z - b.z) >= p.tolerance:
            break
        world.subgoal_index += 1
    else:
        return {}
    target = math.degrees(math.atan2(p.z - b.z, p.x - b.x)) - 90
    diff = target - world.player.yaw
    while diff < -180:
        diff += 360
    while diff > 180:
        diff -= 360
    return {
        "yawDelta": diff / 180.0,
        "nextSubgoal": {"XPos": p.x, "YPos": p.y, "ZPos": p.z, "description": p.description},
    }


def info_json(world: World) -> str:
    """All of the mission's observations as one JSON object string."""
    m = world.mission
    obs: dict[str, object] = {}
    if m.full_stats:
        obs.update(full_stats(world))
    if m.full_inventory:
        obs.update(inventory(world, m.inventory_flat))
    if m.hotbar:
        obs.update(_slots(world, "Hotbar_", 9))
    for r in m.nearby:
        if world.tick_count % r.every == 0:
            obs[r.name] = nearby(world, r.x, r.y, r.z)
    if m.ray:
        los = line_of_sight(world)
        if los:
            obs["LineOfSight"] = los
    b = world.player.body
    for name, x, y, z in m.distances:
        obs["distanceFrom" + name] = math.dist((b.x, b.y, b.z), (x, y, z))
    if m.subgoals:
        obs.update(next_subgoal(world))
    if m.recent_commands and world.recent_commands:
        obs["CommandsSinceLastObservation"] = list(world.recent_commands)
    if m.chat and world.chat_log:
        obs["Chat"] = list(world.chat_log)
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
