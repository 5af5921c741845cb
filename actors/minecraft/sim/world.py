"""The simulated world: voxels, the agent, items and animals, and one ``tick()`` of 50 ms
of game time.

The agents of one multi-agent mission play in one world: the first agent's ``World``
(the host, Malmo's integrated server) owns the blocks, liquids, items and animals, and
each other agent's ``World`` (built with ``share=host``) holds only its own player,
mission, rules and clock on top of them. The host's tick moves the items, animals and
liquids; every agent's tick moves its own player and picks up items. Agents tick under
the host's ``lock``, so one sees the others' changes whole.

A tick applies the commands queued since the last tick (``actions.apply``), then turns,
moves and collides the agent, mines or uses, moves items and animals, picks up items,
spreads liquids, runs the survival rules and finally the mission's rewards and quits.
Rewards add up in ``pending_reward`` until the server hands them to a step.
"""

from __future__ import annotations

import hashlib
import math
import random
import threading
import uuid
from typing import Optional

import numpy as np

from actors.minecraft import blocks as B
from actors.minecraft.malmo.mission import Mission
from actors.minecraft.sim import drawing, extent, interact, worldgen
from actors.minecraft.sim.entities import MOBS, ItemEntity, Mob
from actors.minecraft.sim.physics import JUMP_SPEED, WALK_SPEED, Body, Space, apply_gravity
from actors.minecraft.sim.player import EXHAUSTION, Player
from actors.minecraft.sim.rules import AGENT_DIED, RuleState

MOB_RADIUS = 32.0  # animals further than this from the agent are frozen (not simulated)
LIQUID_DELAY = {B.WATER: 5, B.LAVA: 30}
LIQUID_REACH = {B.WATER: 7, B.LAVA: 3}


def _terrain(
    mission: Mission, seed: int, also: tuple[tuple[float, float, float], ...]
) -> worldgen.Terrain:
    """The mission's terrain, sized to what it places (``extent``) and to the points
    ``also`` (the other agents' placements)."""
    if mission.flat_generator is not None:
        layers = worldgen.flat_layers(mission.flat_generator)
        return worldgen.flat(layers, extent.flat_box(mission, len(layers), also))
    terrain = worldgen.generate(seed)
    if mission.placement is not None:
        terrain = worldgen.recentre(terrain, mission.placement[0], mission.placement[2])
    return worldgen.heighten(terrain, extent.height(mission, 0, terrain.blocks.shape[1], also=also))


class World:
    """One mission's world.

    Args:
        mission: the parsed mission (one agent's part of it).
        seed: world seed (used when the mission does not give one).
        share: the host agent's world, for another agent of the same mission: this
            world then plays on the host's blocks, items and animals (its terrain, seed
            and drawing are the host's) instead of building its own.
        also: more points the terrain must contain (the other agents' placements).
    """

    def __init__(
        self, mission: Mission, seed: int, *, share: Optional[World] = None,
        also: tuple[tuple[float, float, float], ...] = (),
    ) -> None:  # fmt: skip
        self.mission = mission
        self.host: World = self if share is None else share.host
        self.tick_count = 0
        self.world_time = mission.start_time
        self.pending_reward = 0.0
        self.done = False
        self.end_reason = ""
        self.quit_codes: list[str] = []
        self._quits: list[tuple[str, str]] = []
        self.rules = RuleState(mission.rules, float(mission.ms_per_tick or 50))
        self.ignored_commands = 0
        self.craft_log: list[str] = []
        self.chat_log: list[str] = []
        self.recent_commands: list[str] = []
        self.obs_cache: dict[str, object] = {}
        self.time_limit_ticks = (
            math.ceil(mission.time_limit_ms / 50.0) if mission.time_limit_ms is not None else None
        )
        if share is None:
            self.seed = mission.seed if mission.seed is not None else seed
            self.rng = random.Random(self.seed)
            terrain = _terrain(mission, self.seed, also)
            self.blocks = terrain.blocks
            self.x0, self.z0 = terrain.x0, terrain.z0
            self.space = Space(self.blocks, self.x0, self.z0)
            self.lock = threading.RLock()
            self.agents: list[World] = [self]  # every agent's world, the host first
            self.liquid_level: dict[tuple[int, int, int], int] = {}
            self.liquid_due: dict[tuple[int, int, int], int] = {}
            self._version = 0  # bumped on every block change (observation caches key on it)
            self._items: list[ItemEntity] = []
            self._mobs: list[Mob] = []
            self._uid = 0
            self.player_uid = 0
            for name, x, y, z in terrain.mobs:
                self.spawn_mob(name, x, y, z)
            spawn = terrain.spawn
        else:
            h = self.host
            self.seed, self.blocks, self.x0, self.z0 = h.seed, h.blocks, h.x0, h.z0
            self.space, self.lock, self.agents = h.space, h.lock, h.agents
            self.liquid_level, self.liquid_due = h.liquid_level, h.liquid_due
            self.player_uid = h.next_uid()
            self.rng = random.Random(self.seed * 1_000_003 + self.player_uid)
            h.agents.append(self)
            b = h.player.body
            spawn = (b.x, b.y, b.z)  # no placement: next to the host's agent
        yaw = pitch = 0.0
        if mission.placement is not None:
            x, y, z, yaw, pitch = mission.placement
            spawn = (x, y, z)
        self.player: Player = Player(mission.agent_name, Body(*spawn), yaw=yaw, pitch=pitch)
        if share is None:
            for op in mission.drawing:
                drawing.draw(self, op)
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

    # ------------------------------------------------------ shared with the host
    @property
    def version(self) -> int:
        """Block changes so far (observation caches key on it)."""
        return self.host._version

    @version.setter
    def version(self, value: int) -> None:
        self.host._version = value

    @property
    def items(self) -> list[ItemEntity]:
        """Dropped items lying in the world."""
        return self.host._items

    @items.setter
    def items(self, value: list[ItemEntity]) -> None:
        self.host._items = value

    @property
    def mobs(self) -> list[Mob]:
        """Animals in the world."""
        return self.host._mobs

    @mobs.setter
    def mobs(self, value: list[Mob]) -> None:
        self.host._mobs = value

    @property
    def others(self) -> list[Player]:
        """The other agents' players in this world."""
        return [w.player for w in self.agents if w is not self]

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

    def blocks_set_raw(self, x: int, y: int, z: int, block: int) -> None:
        """Set a block without triggering liquids or falling (for decorators)."""
        ix, iz = x - self.x0, z - self.z0
        if 0 <= ix < self.blocks.shape[0] and 0 <= iz < self.blocks.shape[2]:
            if 0 <= y < self.blocks.shape[1]:
                self.blocks[ix, y, iz] = block

    # --------------------------------------------------------------- entities
    def next_uid(self) -> int:
        """A fresh entity number (0 is the host's player)."""
        self.host._uid += 1
        return self.host._uid

    def entity_uuid(self, uid: int) -> str:
        """The entity's id as Malmo reports it: a UUID string, fixed by world seed and
        entity number (no draw from the world's random stream)."""
        digest = hashlib.md5(f"{self.seed}:{uid}".encode()).digest()
        return str(uuid.UUID(bytes=digest, version=4))

    def drop(
        self, item: str, count: int, x: float, y: float, z: float, *, delay: int = 10,
        still: bool = False,
    ) -> None:  # fmt: skip
        """Drop an item stack into the world (tossed a little, unless ``still``)."""
        if count <= 0 or item in ("", "air"):
            return
        body = Body(x, y, z, half_width=0.125, height=0.25)
        if not still:
            body.vx = self.rng.uniform(-0.05, 0.05)
            body.vz = self.rng.uniform(-0.05, 0.05)
            body.vy = 0.1
        self.items.append(ItemEntity(self.next_uid(), item, count, body, pickup_delay=delay))

    def spawn_mob(self, name: str, x: float, y: float, z: float) -> None:
        """Spawn an animal (``name`` must be in ``MOBS``; missions are checked first)."""
        hw, h, hp, _ = MOBS[name]
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
        self.recent_commands, self.chat_log = [], []  # what this tick's observation reports
        for cmd in commands:
            actions.apply(self, cmd)
        c = p.controls
        c.ramp_move()
        if c.turn:  # Malmo accumulates yaw without wrapping it
            p.yaw += c.turn * self.turn_speed / 20.0
        if c.pitch:
            p.pitch = max(-90.0, min(90.0, p.pitch + c.pitch * self.turn_speed / 20.0))
        self._move_player()
        interact.attack_and_use(self)
        self._entities()
        if self.liquid_due and self.host is self:
            self._liquids()
        feet, head = self._cell_at(p.body.y + 0.1), self._cell_at(p.eye[1])
        p.vitals_tick(
            head_in_water=bool(B.IS_WATER[head]),
            in_lava=bool(B.IS_LAVA[feet] or B.IS_LAVA[head]),
            in_water=bool(B.IS_WATER[feet]),
        )
        if self.time_limit_ticks is not None and self.tick_count >= self.time_limit_ticks:
            self.request_quit("time up", self.mission.server_quit_description)
        r = self.mission.rules
        self.rules.tick(self, self._touching() if r.touch or r.quit_touch else [])
        if not p.alive:
            self.request_quit("player died: " + p.death_cause, AGENT_DIED)
        if self._quits:
            self.end("; ".join(r for r, _ in self._quits), [c for _, c in self._quits if c])

    @property
    def turn_speed(self) -> float:
        """ContinuousMovementCommands ``turnSpeedDegs`` (degrees per second)."""
        h = next((h for h in self.mission.handlers if h.kind == "ContinuousMovement"), None)
        return h.turn_speed if h is not None else 180.0

    def chat(self, sender: str, message: str) -> None:
        """A chat message, as Minecraft shows it (``<sender> message``)."""
        self.chat_log.append(f"<{sender}> {message}")

    def request_quit(self, reason: str, code: str = "") -> None:
        """A quit producer fired: the mission ends at the end of this tick with ``code``."""
        self._quits.append((reason, code))

    def end(self, reason: str, codes: Optional[list[str]] = None) -> None:
        """End the mission now (the next step reports done) and pay the mission-end
        rewards for the quit ``codes``."""
        if not self.done:
            self.done = True
            self.end_reason = reason
            self.quit_codes = list(codes or [])
            self.pending_reward += self.rules.final_reward(self.quit_codes)

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
        # The host moves the shared items and animals; every agent picks up for itself.
        p = self.player
        b = p.body
        host = self.host is self
        items = self.items
        if items:
            for it in items:
                ib = it.body
                if host:
                    feet = self.get(math.floor(ib.x), math.floor(ib.y), math.floor(ib.z))
                    it.tick(self.space, bool(B.LIQUID[feet]))
                if (it.count > 0 and it.pickup_delay == 0 and abs(ib.x - b.x) < 1.3 + 0.125
                        and abs(ib.z - b.z) < 1.3 + 0.125
                        and b.y - 0.5 - 0.25 < ib.y < b.y + b.height + 0.5):  # fmt: skip
                    left = p.inventory.add(it.item, it.count)
                    got = it.count - left
                    if got:
                        self.collected(it.item, got)
                    it.count = left
            self.items = [it for it in items if it.count > 0 and it.age < 6000 and it.body.y > -10]
        if not host:
            return
        near = [w.player.body for w in self.agents]
        for m in self.mobs:
            mb = m.body
            for a in near:
                if abs(mb.x - a.x) <= MOB_RADIUS and abs(mb.z - a.z) <= MOB_RADIUS:
                    break
            else:
                continue  # far from every agent: frozen
            feet = self.get(math.floor(mb.x), math.floor(mb.y + 0.1), math.floor(mb.z))
            m.tick(self.space, self.rng, bool(B.LIQUID[feet]))

    def collected(self, item: str, count: int) -> None:
        """Items gained (picked up, crafted or smelted), for rewards and quits."""
        self.rules.gained(self, item, count)

    def lost(self, item: str, count: int) -> None:
        """Items lost (dropped, placed or used up by crafting), for rewards."""
        self.rules.lost(self, item, count)

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

    # ---------------------------------------------------------------- touching
    def _touching(self) -> list[tuple[tuple[int, int, int], str]]:
        """Blocks the player's box, grown by 0.001 on every side, overlaps (Malmo's
        ``PositionHelper.getTouchingBlocks``): the floor, walls and anything inside."""
        b = self.player.body
        w = b.half_width + 0.001
        out = []
        for x in range(math.floor(b.x - w), math.floor(b.x + w) + 1):
            for z in range(math.floor(b.z - w), math.floor(b.z + w) + 1):
                for y in range(math.floor(b.y - 0.001), math.floor(b.y + b.height + 0.001) + 1):
                    bid = self.get(x, y, z)
                    if bid != B.AIR:
                        out.append(((x, y, z), B.NAMES[bid]))
        return out

    def surface_y(self, x: int, z: int) -> int:
        """Height of the highest solid block in a column (for tests and tools)."""
        col = B.SOLID[self.blocks[x - self.x0, :, z - self.z0]]
        nz = np.nonzero(col)[0]
        return int(nz[-1]) if len(nz) else -1
