"""The simulated world: voxels, the agent, items and animals, and one ``tick()`` of 50 ms
of game time.

A tick applies the commands queued since the last tick (``actions.apply``), then turns,
moves and collides the agent, mines or uses, moves items and animals, picks up items,
spreads liquids, runs the survival rules and finally the mission's rewards and quits.
Rewards add up in ``pending_reward`` until the server hands them to a step.
"""

from __future__ import annotations

import math
import random

import numpy as np

from actors.minecraft import blocks as B
from actors.minecraft.malmo.mission import Mission
from actors.minecraft.sim import interact, worldgen
from actors.minecraft.sim.entities import MOBS, ItemEntity, Mob
from actors.minecraft.sim.physics import JUMP_SPEED, WALK_SPEED, Body, Space, apply_gravity
from actors.minecraft.sim.player import EXHAUSTION, Player

MOB_RADIUS = 32.0  # animals further than this from the agent are frozen (not simulated)
LIQUID_DELAY = {B.WATER: 5, B.LAVA: 30}
LIQUID_REACH = {B.WATER: 7, B.LAVA: 3}


class World:
    """One mission's world.

    Args:
        mission: the parsed mission.
        seed: world seed (used when the mission does not give one).
    """

    def __init__(self, mission: Mission, seed: int) -> None:
        self.mission = mission
        self.seed = mission.seed if mission.seed is not None else seed
        if mission.flat_generator is not None:
            terrain = worldgen.flat(mission.flat_generator)
        else:
            terrain = worldgen.generate(self.seed)
        self.blocks = terrain.blocks
        self.x0, self.z0 = terrain.x0, terrain.z0
        self.space = Space(self.blocks, self.x0, self.z0)
        self.rng = random.Random(self.seed)
        self.tick_count = 0
        self.version = 0  # bumped on every block change (observation caches key on it)
        self.world_time = mission.start_time
        self.items: list[ItemEntity] = []
        self.mobs: list[Mob] = []
        self._uid = 0
        self.pending_reward = 0.0
        self.done = False
        self.end_reason = ""
        self.liquid_level: dict[tuple[int, int, int], int] = {}
        self.liquid_due: dict[tuple[int, int, int], int] = {}
        self.touched: set[tuple[str, tuple[int, int, int]]] = set()
        self.ignored_commands = 0
        self.craft_log: list[str] = []
        self.obs_cache: dict[str, object] = {}
        self.time_limit_ticks = (
            math.ceil(mission.time_limit_ms / 50.0) if mission.time_limit_ms is not None else None
        )
        for name, x, y, z in terrain.mobs:
            self.spawn_mob(name, x, y, z)
        spawn = terrain.spawn
        yaw = pitch = 0.0
        if mission.placement is not None:
            x, y, z, yaw, pitch = mission.placement
            spawn = (x, y, z)
        self.player = Player(mission.agent_name, Body(*spawn), yaw=yaw, pitch=pitch)
        for op in mission.drawing:
            self._draw(op.kind, op.coords, op.type)
        for slot, item, qty in mission.start_inventory:
            from actors.minecraft.sim.inventory import Stack

            tool = B.TOOLS.get(item)
            if 0 <= slot < len(self.player.inventory.slots) and item != "air":
                self.player.inventory.slots[slot] = Stack(item, qty, tool.durability if tool else 0)
        self.player.body.on_ground = self.space.box_solid(
            spawn[0] - 0.3,
            spawn[1] - 0.05,
            spawn[2] - 0.3,
            spawn[0] + 0.3,
            spawn[1],
            spawn[2] + 0.3,
        )

    # ----------------------------------------------------------------- blocks
    def get(self, x: int, y: int, z: int) -> int:
        """Block id at world coordinates (bedrock outside the sides/bottom, air above)."""
        ix, iz = x - self.x0, z - self.z0
        if y < 0 or not (0 <= ix < self.blocks.shape[0] and 0 <= iz < self.blocks.shape[2]):
            return B.BEDROCK
        if y >= self.blocks.shape[1]:
            return B.AIR
        return int(self.blocks[ix, y, iz])

    def set(self, x: int, y: int, z: int, block: int) -> None:
        """Set a block; removing one lets neighbouring liquids flow and sand fall."""
        ix, iz = x - self.x0, z - self.z0
        if not (0 <= ix < self.blocks.shape[0] and 0 <= iz < self.blocks.shape[2]):
            return
        if not 0 <= y < self.blocks.shape[1]:
            return
        self.blocks[ix, y, iz] = block
        self.version += 1
        self.liquid_level.pop((x, y, z), None)
        if not B.SOLID[block]:
            self._wake_liquids(x, y, z)
            above = self.get(x, y + 1, z)
            if B.FALLS[above] and block == B.AIR:
                self._fall(x, y + 1, z)

    def _fall(self, x: int, y: int, z: int) -> None:
        while B.FALLS[self.get(x, y, z)]:
            b = self.get(x, y, z)
            ty = y
            while ty - 1 >= 0 and not B.SOLID[self.get(x, ty - 1, z)]:
                ty -= 1
            if ty == y:
                return
            self.blocks[x - self.x0, y, z - self.z0] = B.AIR
            self.blocks[x - self.x0, ty, z - self.z0] = b
            self.version += 1
            self._wake_liquids(x, y, z)
            y += 1

    def _draw(self, kind: str, c: tuple[float, ...], type_: str) -> None:
        if kind == "block":
            self.blocks_set_raw(int(c[0]), int(c[1]), int(c[2]), B.block_id(type_))
        elif kind == "cuboid":
            bid = B.block_id(type_)
            lo = [int(min(a, b)) for a, b in zip(c[:3], c[3:], strict=True)]
            hi = [int(max(a, b)) for a, b in zip(c[:3], c[3:], strict=True)]
            sx, sy, sz = self.blocks.shape
            x1, x2 = max(lo[0] - self.x0, 0), min(hi[0] - self.x0 + 1, sx)
            y1, y2 = max(lo[1], 0), min(hi[1] + 1, sy)
            z1, z2 = max(lo[2] - self.z0, 0), min(hi[2] - self.z0 + 1, sz)
            if x1 < x2 and y1 < y2 and z1 < z2:
                self.blocks[x1:x2, y1:y2, z1:z2] = bid
        elif kind == "item":
            self.drop(type_.removeprefix("minecraft:"), 1, c[0], c[1], c[2], delay=0)
        elif kind == "entity":
            self.spawn_mob(type_, c[0], c[1], c[2])

    def blocks_set_raw(self, x: int, y: int, z: int, block: int) -> None:
        """Set a block without triggering liquids or falling (for decorators)."""
        ix, iz = x - self.x0, z - self.z0
        if 0 <= ix < self.blocks.shape[0] and 0 <= iz < self.blocks.shape[2]:
            if 0 <= y < self.blocks.shape[1]:
                self.blocks[ix, y, iz] = block

    # --------------------------------------------------------------- entities
    def next_uid(self) -> int:
        """A fresh entity id."""
        self._uid += 1
        return self._uid

    def drop(self, item: str, count: int, x: float, y: float, z: float, *, delay: int = 10):
        """Drop an item stack into the world."""
        if count <= 0 or item in ("", "air"):
            return
        body = Body(x, y, z, half_width=0.125, height=0.25)
        body.vx = self.rng.uniform(-0.05, 0.05)
        body.vz = self.rng.uniform(-0.05, 0.05)
        body.vy = 0.1
        self.items.append(ItemEntity(self.next_uid(), item, count, body, pickup_delay=delay))

    def spawn_mob(self, name: str, x: float, y: float, z: float) -> None:
        """Spawn an animal (unknown names are ignored, as Malmo ignores unknown entities)."""
        spec = MOBS.get(name)
        if spec is None:
            return
        hw, h, hp, _ = spec
        body = Body(x, y, z, half_width=hw, height=h)
        self.mobs.append(Mob(self.next_uid(), name, body, hp, ai_timer=self.rng.randint(0, 100)))

    # ------------------------------------------------------------------- ticks
    def tick(self, commands: list[str]) -> None:
        """Advance one tick, applying ``commands`` first."""
        from actors.minecraft.sim import actions

        if self.done:
            return
        self.tick_count += 1
        if self.mission.passage_of_time:
            self.world_time += 1
        p = self.player
        for cmd in commands:
            actions.apply(self, cmd)
            if self.done:
                return
        c = p.controls
        h0 = self.mission.handler_for("turn")
        speed = h0.turn_speed if h0 is not None else 180.0
        if c.turn:
            p.yaw = (p.yaw + c.turn * speed / 20.0) % 360.0
        if c.pitch:
            p.pitch = max(-90.0, min(90.0, p.pitch + c.pitch * speed / 20.0))
        self._move_player()
        interact.attack_and_use(self)
        self._entities()
        if self.liquid_due:
            self._liquids()
        feet, head = self._cell_at(p.body.y + 0.1), self._cell_at(p.eye[1])
        p.vitals_tick(
            head_in_water=bool(B.IS_WATER[head]),
            in_lava=bool(B.IS_LAVA[feet] or B.IS_LAVA[head]),
            in_water=bool(B.IS_WATER[feet]),
        )
        self._rewards_and_quits()
        if not p.alive:
            self.end("player died: " + p.death_cause)

    def end(self, reason: str) -> None:
        """End the mission (the next step reports done)."""
        if not self.done:
            self.done = True
            self.end_reason = reason

    def _cell_at(self, y: float) -> int:
        b = self.player.body
        return self.get(math.floor(b.x), math.floor(y), math.floor(b.z))

    def _move_player(self) -> None:
        p, b, c = self.player, self.player.body, self.player.controls
        feet = self._cell_at(b.y + 0.1)
        in_liquid = bool(B.LIQUID[feet])
        speed = WALK_SPEED * (0.3 if c.crouch else 1.0) * (0.5 if in_liquid else 1.0)
        yr = math.radians(p.yaw)
        fx, fz = -math.sin(yr), math.cos(yr)
        # Malmo: strafe 1 moves right, i.e. towards (-fz, fx) in this frame.
        b.vx = (c.move * fx - c.strafe * fz) * speed
        b.vz = (c.move * fz + c.strafe * fx) * speed
        if c.jump and b.on_ground and not in_liquid:
            b.vy = JUMP_SPEED
            p.exhaustion += EXHAUSTION["jump"]
        if c.jump and in_liquid:
            b.vy = 0.1
        x, y, z = b.x, b.y, b.z
        _, landed = self.space.move(b)
        # Minecraft moves first and applies gravity after: a jump rises 0.42 + 0.33 + ...
        apply_gravity(b, in_liquid)
        dist = math.sqrt((b.x - x) ** 2 + (b.z - z) ** 2)
        p.distance += dist
        p.exhaustion += dist * EXHAUSTION["swim" if in_liquid else "walk"]
        if in_liquid:
            b.fall_distance = 0.0
        elif b.y < y:
            b.fall_distance += y - b.y
        if landed or (b.on_ground and b.fall_distance > 0):
            p.land()
        if b.y < -10:
            p.hurt(1000.0, "fell out of the world")

    # --------------------------------------------------------------- entities
    def _entities(self) -> None:
        p = self.player
        b = p.body
        if self.items:
            keep = []
            for it in self.items:
                ib = it.body
                feet = self.get(math.floor(ib.x), math.floor(ib.y), math.floor(ib.z))
                it.tick(self.space, bool(B.LIQUID[feet]))
                if (it.pickup_delay == 0 and abs(ib.x - b.x) < 1.3 + 0.125
                        and abs(ib.z - b.z) < 1.3 + 0.125
                        and b.y - 0.5 - 0.25 < ib.y < b.y + b.height + 0.5):  # fmt: skip
                    left = p.inventory.add(it.item, it.count)
                    got = it.count - left
                    if got:
                        self.collected(it.item, got)
                    it.count = left
                if it.count > 0 and it.age < 6000 and ib.y > -10:
                    keep.append(it)
            self.items = keep
        for m in self.mobs:
            mb = m.body
            if abs(mb.x - b.x) > MOB_RADIUS or abs(mb.z - b.z) > MOB_RADIUS:
                continue
            feet = self.get(math.floor(mb.x), math.floor(mb.y + 0.1), math.floor(mb.z))
            m.tick(self.space, self.rng, bool(B.LIQUID[feet]))

    def collected(self, item: str, count: int) -> None:
        """Count items gained (picked up or crafted) for rewards and quits."""
        r = self.mission.collect_rewards.get(item)
        if r is not None:
            self.pending_reward += r * count
        if item in self.mission.quit_collect:
            self.end(f"collected {item}")

    # ----------------------------------------------------------------- liquids
    def _wake_liquids(self, x: int, y: int, z: int) -> None:
        for dx, dy, dz in ((0, 1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1)):
            n = self.get(x + dx, y + dy, z + dz)
            if B.LIQUID[n]:
                kind = B.WATER if B.IS_WATER[n] else B.LAVA
                self.liquid_due.setdefault((x, y, z), self.tick_count + LIQUID_DELAY[kind])

    def _liquids(self) -> None:
        now = self.tick_count
        due = [c for c, t in self.liquid_due.items() if t <= now]
        for c in due:
            del self.liquid_due[c]
            x, y, z = c
            if self.get(x, y, z) not in (B.AIR, B.ID["torch"]):
                continue
            above = self.get(x, y + 1, z)
            level = None
            kind = B.AIR
            if B.LIQUID[above]:
                kind, level = (B.WATER if B.IS_WATER[above] else B.LAVA), 0
            else:
                for dx, dz in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                    n = self.get(x + dx, y, z + dz)
                    if not B.LIQUID[n]:
                        continue
                    k = B.WATER if B.IS_WATER[n] else B.LAVA
                    lv = self.liquid_level.get((x + dx, y, z + dz), 0) + 1
                    if lv <= LIQUID_REACH[k] and (level is None or lv < level):
                        kind, level = k, lv
            if level is None:
                continue
            flowing = B.FLOWING_WATER if kind == B.WATER else B.FLOWING_LAVA
            self.blocks[x - self.x0, y, z - self.z0] = flowing
            self.version += 1
            self.liquid_level[c] = level
            for dx, dy, dz in ((0, -1, 0), (1, 0, 0), (-1, 0, 0), (0, 0, 1), (0, 0, -1)):
                nb = (x + dx, y + dy, z + dz)
                if self.get(*nb) == B.AIR:
                    self.liquid_due.setdefault(nb, now + LIQUID_DELAY[kind])

    # ---------------------------------------------------------- rewards, quits
    def _rewards_and_quits(self) -> None:
        m = self.mission
        if self.time_limit_ticks is not None and self.tick_count >= self.time_limit_ticks:
            self.end("time up")
        b = self.player.body
        if m.touch_rewards or m.quit_touch:
            cells = self._touching()
            for cell, bid in cells:
                name = B.NAMES[bid]
                for tr in m.touch_rewards:
                    if name not in tr.types:
                        continue
                    key = (name, cell) if tr.behaviour == "oncePerBlock" else (name, (0, 0, 0))
                    if tr.behaviour == "constant" or key not in self.touched:
                        self.pending_reward += tr.reward
                        self.touched.add(key)
                if name in m.quit_touch:
                    self.end(f"touched {name}")
        for x, y, z, tol in m.quit_positions:
            if (b.x - x) ** 2 + (b.y - y) ** 2 + (b.z - z) ** 2 <= tol * tol:
                self.end("reached position")

    def _touching(self) -> list[tuple[tuple[int, int, int], int]]:
        b = self.player.body
        w = b.half_width
        out = []
        for x in range(math.floor(b.x - w), math.floor(b.x + w - 1e-6) + 1):
            for z in range(math.floor(b.z - w), math.floor(b.z + w - 1e-6) + 1):
                for y in range(math.floor(b.y - 0.01), math.floor(b.y + b.height) + 1):
                    bid = self.get(x, y, z)
                    if bid != B.AIR:
                        out.append(((x, y, z), bid))
        return out

    def surface_y(self, x: int, z: int) -> int:
        """Height of the highest solid block in a column (for tests and tools)."""
        col = B.SOLID[self.blocks[x - self.x0, :, z - self.z0]]
        nz = np.nonzero(col)[0]
        return int(nz[-1]) if len(nz) else -1
