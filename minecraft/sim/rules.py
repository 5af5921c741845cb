"""The mission's reward and quit producers at run time, with Malmo's semantics.

Events arrive from the world (items gained or lost, damage dealt, commands handled) and
once per tick (blocks touched, positions reached, time). Rewards add to the world's
``pending_reward``; a quit asks the world to end at the end of the tick with a quit
code, the handler's ``description``. When the mission ends, ``RewardForMissionEnd``
pays the cases whose description matches one of the quit codes (case-insensitively;
``MALMO_AGENT_DIED`` pays ``rewardForDeath``), as Malmo's final reward does.

The producers see a world only as a ``Scene``, what they read and change of it, so they
sit below ``state.WorldState``, which holds them.
"""

from __future__ import annotations

import math
import re
from typing import Protocol

from minecraft import blocks as B
from minecraft.malmo.mission_rules import Rules
from minecraft.sim.entities import Mob
from minecraft.sim.player import Player

AGENT_DIED = "MALMO_AGENT_DIED"  # Malmo's quit code when the player dies


class Scene(Protocol):
    """What the producers read and change of an agent's world (``state.WorldState``)."""

    tick_count: int
    pending_reward: float
    player: Player

    @property
    def mobs(self) -> list[Mob]:
        """The animals in the world."""
        ...

    @property
    def others(self) -> list[Player]:
        """The other agents' players."""
        ...

    def get(self, x: int, y: int, z: int) -> int:
        """The block id at a cell."""
        ...

    def request_quit(self, reason: str, code: str = "") -> None:
        """End the mission at the end of this tick with quit ``code``."""
        ...


def trapped(world: Scene) -> list[tuple[str, tuple[int, int]]]:
    """Mobs that cannot step away, as Malmo's RewardForCatchingMob sees it: at the
    agent's height, with no north/south/east/west neighbour that is air and free of a
    player (any agent of the mission). Returns (mob name, (x, z) cell) pairs."""
    b = world.player.body
    players = {
        (math.floor(a.x), math.floor(a.y), math.floor(a.z))
        for a in (q.body for q in [world.player, *world.others])
    }
    out = []
    for m in world.mobs:
        x, y, z = (int(v) for v in (m.body.x, m.body.y, m.body.z))  # Java's (int) casts
        if y != int(b.y):
            continue
        free = any(
            world.get(x + dx, y, z + dz) == B.AIR and (x + dx, y, z + dz) not in players
            for dx, dz in ((1, 0), (-1, 0), (0, 1), (0, -1))
        )
        if not free:
            out.append((m.name, (math.floor(m.body.x), math.floor(m.body.z))))
    return out


def _next_to(cell: tuple[int, int], here: tuple[int, int]) -> bool:
    return abs(cell[0] - here[0]) + abs(cell[1] - here[1]) <= 1


class RuleState:
    """Per-mission state of the reward and quit producers.

    Args:
        rules: the mission's rules.
        ms_per_tick: real milliseconds per tick (for ``oncePerTimeSpan`` cooldowns,
            which Malmo measures on the wall clock).
    """

    def __init__(self, rules: Rules, ms_per_tick: float) -> None:
        self.rules = rules
        self.ms_per_tick = ms_per_tick
        self.touch_fired = [False] * len(rules.touch)
        self.touch_blocks: list[set[tuple[int, int, int]]] = [set() for _ in rules.touch]
        self.touch_last_ms = [-math.inf] * len(rules.touch)
        self.positions = list(rules.positions)
        self.time_total = rules.time.initial if rules.time is not None else 0.0
        self.quota_total = rules.quota_total[0] if rules.quota_total is not None else None
        self.quotas = [q.quota for q in rules.quotas]
        self.chat = [(re.compile(rx), r) for rx, r in rules.chat]

    # ---------------------------------------------------------------- events
    def gained(self, world: Scene, item: str, count: int) -> None:
        """Items picked up, crafted or smelted: RewardForCollectingItem and its quit."""
        for r in self.rules.collect:
            if item in r.types:
                world.pending_reward += r.reward * count
        for q in self.rules.quit_collect:
            if item in q.types:
                world.request_quit(f"collected {item}", q.description)

    def lost(self, world: Scene, item: str, count: int) -> None:
        """Items dropped, placed or used up by crafting: RewardForDiscardingItem."""
        for r in self.rules.discard:
            if item in r.types:
                world.pending_reward += r.reward * count

    def damaged(self, world: Scene, mob: str, amount: float) -> None:
        """The agent hurt a mob: RewardForDamagingEntity, per point of damage."""
        for r in self.rules.damage:
            if mob in r.types:
                world.pending_reward += r.reward * amount

    def handled(self, world: Scene, verb: str, parameter: str) -> None:
        """A command a handler took: RewardForSendingCommand, chat rewards, quotas."""
        if self.rules.command_reward is not None:
            world.pending_reward += self.rules.command_reward
        if verb == "chat":
            for rx, reward in self.chat:
                if rx.fullmatch(parameter):
                    world.pending_reward += reward
        if self.quota_total is not None:
            self.quota_total -= 1
            if self.quota_total == 0:
                assert self.rules.quota_total is not None
                world.request_quit("command quota reached", self.rules.quota_total[1])
                return  # the total takes precedence, as in Malmo
        for i, q in enumerate(self.rules.quotas):
            if verb in q.verbs:
                self.quotas[i] -= 1
                if self.quotas[i] == 0:
                    world.request_quit("command quota reached", q.description)
                    return

    # ------------------------------------------------------------------ tick
    def tick(self, world: Scene, touching: list[tuple[tuple[int, int, int], str]]) -> None:
        """Per-tick producers: touching, positions, time taken, agent time limit."""
        now_ms = world.tick_count * self.ms_per_tick
        for i, spec in enumerate(self.rules.touch):
            for cell, name in touching:
                if name not in spec.types or not self._touch_applies(i, cell, now_ms):
                    continue
                world.pending_reward += spec.reward
                self.touch_fired[i] = True
                self.touch_last_ms[i] = now_ms
                if spec.behaviour == "oncePerBlock":
                    self.touch_blocks[i].add(cell)
        for q in self.rules.quit_touch:
            hit = next((name for _, name in touching if name in q.types), None)
            if hit is not None:
                world.request_quit(f"touched {hit}", q.description)
        b = world.player.body
        for m in list(self.positions):
            if math.dist((b.x, b.y, b.z), (m.x, m.y, m.z)) <= m.tolerance:
                world.pending_reward += m.reward
                if m.oneshot:
                    self.positions.remove(m)
        for m_quit in self.rules.quit_positions:
            if math.dist((b.x, b.y, b.z), (m_quit.x, m_quit.y, m_quit.z)) <= m_quit.tolerance:
                world.request_quit("reached position", m_quit.description)
        t = self.rules.time
        if t is not None:
            if t.density == "PER_TICK":
                world.pending_reward += t.delta
            else:
                self.time_total += t.delta
                if t.density == "PER_TICK_ACCUMULATED":
                    world.pending_reward += self.time_total
        if self.rules.catch or self.rules.quit_catch:
            self._catching(world)
        if self.rules.quit_time is not None:
            limit, description = self.rules.quit_time
            if world.tick_count * 50.0 >= limit:
                world.request_quit("agent time up", description)

    def _catching(self, world: Scene) -> None:
        """RewardForCatchingMob, every tick a mob stays trapped (Malmo's ``oneshot`` never
        takes effect), and AgentQuitFromCatchingMob."""
        caught = trapped(world)
        b = world.player.body
        here = (math.floor(b.x), math.floor(b.z))
        for rule in self.rules.catch:
            for name, cell in caught:
                if name in rule.types and (rule.everywhere or _next_to(cell, here)):
                    world.pending_reward += rule.reward
        for rule in self.rules.quit_catch:
            if any(n in rule.types and (rule.everywhere or _next_to(c, here)) for n, c in caught):
                world.request_quit("caught a mob", rule.description)
                break

    def _touch_applies(self, i: int, cell: tuple[int, int, int], now_ms: float) -> bool:
        behaviour = self.rules.touch[i].behaviour
        if behaviour == "onceOnly":
            return not self.touch_fired[i]
        if behaviour == "oncePerBlock":
            return cell not in self.touch_blocks[i]
        if behaviour == "oncePerTimeSpan":
            return now_ms - self.touch_last_ms[i] > self.rules.touch[i].cooldown_ms
        return True  # constant

    # ------------------------------------------------------------------- end
    def final_reward(self, codes: list[str]) -> float:
        """RewardForMissionEnd for the quit codes, plus a MISSION_END time reward."""
        total = 0.0
        for code in codes:
            for description, reward in self.rules.mission_end:
                if description.lower() == code.lower():
                    total += reward
            if code == AGENT_DIED:
                total += self.rules.death_reward
        t = self.rules.time
        if t is not None and t.density == "MISSION_END":
            total += self.time_total
        return total
