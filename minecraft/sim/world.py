"""One ``tick()`` of 50 ms of game time in the simulated world, and the world built for a
mission: its state (terrain, player, inventory), then the mission's drawing.

The world's contents and the changes every part of a tick makes to them are
``state.WorldState``; the host's tick moves the items, animals and liquids; every
agent's tick moves its own player and picks up items. Agents tick under the host's
``lock``, so one sees the others' changes whole.

A tick applies the commands queued since the last tick (``actions.apply``), then turns,
moves and collides the agent, mines or uses, moves items and animals, picks up items,
spreads liquids, runs the survival rules and finally the mission's rewards and quits.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from minecraft import blocks as B
from minecraft.malmo.mission import Mission
from minecraft.sim import actions, drawing, interact
from minecraft.sim.physics import JUMP_SPEED, WALK_SPEED, apply_gravity
from minecraft.sim.player import EXHAUSTION, VOID
from minecraft.sim.rules import AGENT_DIED
from minecraft.sim.state import LIQUID_DELAY, WorldState

MOB_RADIUS = 32.0  # animals further than this from the agent are frozen (not simulated)
LIQUID_REACH = {B.WATER: 7, B.LAVA: 3}


class World(WorldState):
    """One mission's world: its state, drawn as the mission says, and its tick.

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
        super().__init__(mission, seed, share=share, also=also)
        if share is None:
            for op in self.mission.drawing:
                drawing.draw(self, op)
        b = self.player.body
        b.on_ground = self.space.box_solid(
            b.x - 0.3, b.y - 0.05, b.z - 0.3, b.x + 0.3, b.y, b.z + 0.3
        )

    # ------------------------------------------------------------------- ticks
    def tick(self, commands: list[str]) -> None:
        """Advance one tick, applying ``commands`` first."""
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
        self._build_battle()
        r = self.mission.rules
        self.rules.tick(self, self._touching() if r.touch or r.quit_touch else [])
        if not p.alive:
            self.request_quit("player died: " + p.death_cause, AGENT_DIED)
        if self._quits:
            self.end("; ".join(r for r, _ in self._quits), [c for _, c in self._quits if c])

    def _build_battle(self) -> None:
        # The host scores the copy for every agent; each agent collects its reward.
        arena = self.build_battle
        if arena is not None and self.host is self:
            scored = arena.update(self)
            if scored is not None:
                for w in self.agents:
                    w.copying.scored(*scored)
        self.copying.pay(self, self.agents, [w.player.name for w in self.agents], end=False)
        spec = self.mission.rules.copying
        if spec is not None and spec.quit is not None and self.copying.complete:
            self.request_quit("structure copied", spec.quit)

    @property
    def turn_speed(self) -> float:
        """ContinuousMovementCommands ``turnSpeedDegs`` (degrees per second)."""
        h = next((h for h in self.mission.handlers if h.kind == "ContinuousMovement"), None)
        return h.turn_speed if h is not None else 180.0

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
            p.hurt(1000.0, VOID)

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
