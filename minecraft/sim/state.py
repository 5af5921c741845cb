"""What one mission's world holds, and the changes every part of a tick makes to it:
blocks (setting one wakes liquids and drops sand), the player, dropped items and animals,
and the rewards and quits the mission's producers (``rules.RuleState``) decide.

The agents of one multi-agent mission play in one world: the first agent's state (the
host, Malmo's integrated server) owns the blocks, liquids, items and animals, and each
other agent's (built with ``share=host``) holds only its own player, mission, rules and
clock on top of them. Rewards add up in ``pending_reward`` until the server hands them to
a step; quits requested during a tick end the mission at its end.

This sits below the commands, the hands and the drawing that change it (``actions``,
``interact``, ``drawing``) and ``world.World``, which builds it and runs the tick.
"""

from __future__ import annotations

import hashlib
import math
import random
import threading
import uuid
import weakref
from typing import Optional

from minecraft import blocks as B
from minecraft.malmo.mission import Mission
from minecraft.sim import decorators, extent, worldgen
from minecraft.sim.decorators.build_battle import BuildBattle, Copying
from minecraft.sim.entities import MOBS, ItemEntity, Mob
from minecraft.sim.inventory import Stack
from minecraft.sim.physics import Body, Space
from minecraft.sim.player import Player
from minecraft.sim.rules import RuleState

LIQUID_DELAY = {B.WATER: 5, B.LAVA: 30}  # ticks before a liquid flows into a freed cell


def _terrain(
    mission: Mission, seed: int, also: tuple[tuple[float, float, float], ...]
) -> worldgen.Terrain:
    """The mission's terrain, sized to what it places (``extent``) and to the points
    ``also`` (the other agents' placements)."""
    if mission.flat_generator is not None:
        layers = worldgen.flat_layers(mission.flat_generator)
        return worldgen.flat(layers, extent.flat_box(mission, len(layers), also))
    keep = 1.0 if mission.diamond_keep is None else mission.diamond_keep
    terrain = worldgen.generate(seed, diamond_keep=keep)
    if mission.placement is not None:
        terrain = worldgen.recentre(terrain, mission.placement[0], mission.placement[2])
    return worldgen.heighten(terrain, extent.height(mission, 0, terrain.blocks.shape[1], also=also))


class WorldState:
    """One mission's world, as it stands between ticks.

    Args:
        mission: the parsed mission (one agent's part of it).
        seed: world seed (used when the mission does not give one).
        share: the host agent's world, for another agent of the same mission: this
            world then plays on the host's blocks, items and animals (its terrain and
            seed are the host's) instead of building its own.
        also: more points the terrain must contain (the other agents' placements).
    """

    def __init__(
        self, mission: Mission, seed: int, *, share: Optional[WorldState] = None,
        also: tuple[tuple[float, float, float], ...] = (),
    ) -> None:  # fmt: skip
        # No reference cycles (a world is freed the moment its instance lets it go, not at
        # the next full collection, which a large process such as an env actor seldom
        # runs): the host is itself through `host`, guests are held weakly.
        self._host: Optional[WorldState] = None if share is None else share.host
        self._guests: list[weakref.ref[WorldState]] = []
        if share is None:
            self.seed = mission.seed if mission.seed is not None else seed
        else:
            self.seed = self.host.seed
        # The maze and classroom, built from the world's seed: drawing, start, quits.
        self.mission = mission = decorators.expand(mission, self.seed)
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
        self.subgoal_index = 0  # ObservationFromSubgoalPositionList's next point
        self.time_limit_ticks = (
            math.ceil(mission.time_limit_ms / 50.0) if mission.time_limit_ms is not None else None
        )
        self.copying = Copying(mission.rules.copying, mission.agent_name)
        if share is None:
            self.rng = random.Random(self.seed)
            terrain = _terrain(mission, self.seed, also)
            self.blocks = terrain.blocks
            self.x0, self.z0 = terrain.x0, terrain.z0
            self.space = Space(self.blocks, self.x0, self.z0)
            self.lock = threading.RLock()
            self.liquid_level: dict[tuple[int, int, int], int] = {}
            self.liquid_due: dict[tuple[int, int, int], int] = {}
            self._version = 0  # bumped on every block change (observation caches key on it)
            self._items: list[ItemEntity] = []
            self._mobs: list[Mob] = []
            self._uid = 0
            self.player_uid = 0
            spec = mission.build_battle
            self.build_battle: Optional[BuildBattle] = BuildBattle(spec) if spec else None
            for name, x, y, z in terrain.mobs:
                self.spawn_mob(name, x, y, z)
            spawn = terrain.spawn
        else:
            h = self.host
            self.blocks, self.x0, self.z0 = h.blocks, h.x0, h.z0
            self.build_battle = h.build_battle
            self.space, self.lock = h.space, h.lock
            self.liquid_level, self.liquid_due = h.liquid_level, h.liquid_due
            self.player_uid = h.next_uid()
            self.rng = random.Random(self.seed * 1_000_003 + self.player_uid)
            h._guests.append(weakref.ref(self))
            b = h.player.body
            spawn = (b.x, b.y, b.z)  # no placement: next to the host's agent
        yaw = pitch = 0.0
        if mission.placement is not None:
            x, y, z, yaw, pitch = mission.placement
            spawn = (x, y, z)
        self.player: Player = Player(mission.agent_name, Body(*spawn), yaw=yaw, pitch=pitch)
        self.player.creative = mission.mode == "Creative"

        for slot, item, qty in mission.start_inventory:
            tool = B.TOOLS.get(item)
            if 0 <= slot < len(self.player.inventory.slots) and item != "air":
                self.player.inventory.slots[slot] = Stack(item, qty, tool.durability if tool else 0)

    # ------------------------------------------------------ shared with the host
    @property
    def host(self) -> WorldState:
        """The world whose blocks, items and animals this one plays on: its own, or the
        mission's first agent's."""
        return self if self._host is None else self._host

    @property
    def agents(self) -> list[WorldState]:
        """Every agent's world of this mission still in play, the host first."""
        host = self.host
        return [host, *(g for ref in host._guests if (g := ref()) is not None)]

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

    # ------------------------------------------------------ rewards and quits
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
            names = [w.player.name for w in self.agents]
            self.copying.pay(self, self.agents, names, end=True)

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
