"""Dropped items and passive animals (pigs, cows, chickens, sheep and rabbits, the
agent's meat)."""

from __future__ import annotations

import math
import random
from dataclasses import dataclass

from minecraft.sim.physics import WALK_SPEED, Body, Space, apply_gravity

ITEM_LIFETIME = 6000  # ticks before a dropped item despawns, as in Minecraft
MOBS: dict[str, tuple[float, float, float, str]] = {
    # name: (half width, height, health, meat)
    "Pig": (0.45, 0.9, 10.0, "porkchop"),
    "Cow": (0.45, 1.4, 10.0, "beef"),
    "Chicken": (0.2, 0.7, 4.0, "chicken"),
    "Sheep": (0.45, 1.3, 8.0, "mutton"),
    "Rabbit": (0.2, 0.5, 3.0, "rabbit"),
}


@dataclass
class ItemEntity:
    """An item stack lying in the world.

    Attributes:
        uid: entity id.
        item: item name.
        count: stack size.
        body: physics box (0.25 blocks).
        age: ticks since dropped.
        pickup_delay: ticks before it can be picked up.
    """

    uid: int
    item: str
    count: int
    body: Body
    age: int = 0
    pickup_delay: int = 10

    def tick(self, space: Space, in_liquid: bool) -> None:
        """Fall and settle; resting items cost nothing."""
        self.age += 1
        if self.pickup_delay > 0:
            self.pickup_delay -= 1
        b = self.body
        if b.on_ground and b.vx == 0.0 and b.vz == 0.0 and self.age % 10:
            return
        apply_gravity(b, in_liquid)
        b.vx *= 0.6
        b.vz *= 0.6
        if abs(b.vx) < 1e-3:
            b.vx = 0.0
        if abs(b.vz) < 1e-3:
            b.vz = 0.0
        space.move(b)
        if b.on_ground and b.vy <= 0:
            b.vy = 0.0


@dataclass
class Mob:
    """A passive animal that wanders.

    Attributes:
        uid: entity id.
        name: Malmo entity name (``"Pig"``, ``"Cow"``).
        body: physics box.
        health: hit points.
        yaw: facing, degrees.
        walking: currently wandering.
        ai_timer: ticks until the next wander decision.
        hurt_timer: ticks of fleeing after being hit.
    """

    uid: int
    name: str
    body: Body
    health: float
    yaw: float = 0.0
    walking: bool = False
    ai_timer: int = 0
    hurt_timer: int = 0

    def tick(self, space: Space, rng: random.Random, in_liquid: bool) -> None:
        """Wander: pick a direction now and then, hop over one-block steps."""
        self.ai_timer -= 1
        if self.hurt_timer > 0:
            self.hurt_timer -= 1
        if self.ai_timer <= 0:
            self.ai_timer = rng.randint(40, 140)
            self.walking = rng.random() < 0.3
            self.yaw = rng.uniform(0.0, 360.0)
        b = self.body
        if not self.walking and self.hurt_timer == 0 and b.on_ground and not in_liquid:
            b.vx = b.vz = 0.0
            return
        speed = WALK_SPEED * (0.45 if self.hurt_timer == 0 else 0.9)
        yr = math.radians(self.yaw)
        b.vx, b.vz = -math.sin(yr) * speed, math.cos(yr) * speed
        if in_liquid:
            b.vy = max(b.vy, 0.04)
        hit, landed = space.move(b)
        apply_gravity(b, in_liquid)
        if hit and b.on_ground:
            b.vy = 0.42
