"""The agent's state (body, controls, vitals, statistics) and Minecraft's survival rules:
hunger and exhaustion, natural regeneration, starvation, drowning, lava and fire, falls.

Numbers follow Minecraft 1.11 (normal difficulty): 20 health, 20 food with saturation,
4 exhaustion per food point, regeneration of 1 health per 80 ticks while food >= 18,
300 ticks of air, 2 damage per second when drowning, 4 damage per half second in lava,
fall damage ``ceil(distance - 3)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from minecraft.sim.crafting import CraftState
from minecraft.sim.inventory import Inventory
from minecraft.sim.physics import Body

EXHAUSTION = {
    "walk": 0.01,  # per block
    "swim": 0.01,  # per block
    "jump": 0.05,
    "break": 0.005,
    "attack": 0.1,
    "damage": 0.1,
    "regen": 6.0,
}
MAX_AIR = 300
VOID = "fell out of the world"  # the one damage a Creative player takes


INERTIA_TICKS = 6  # Malmo's ContinuousMovement ramp from one "move" speed to the next


@dataclass
class Controls:
    """Continuous movement states, as set by ContinuousMovementCommands (they persist).

    ``move`` is the forward speed in use; a ``move`` command sets ``move_target`` and the
    speed ramps towards it over 6 ticks, as Malmo's ContinuousMovement does: on the k-th
    tick after the change it closes k/6 of the remaining gap (0 -> 1: 0.17, 0.44, 0.72,
    0.91, 0.98, 1). Strafe, turn and pitch take effect at once.
    """

    move: float = 0.0
    move_target: float = 0.0
    move_ticks: int = 0
    strafe: float = 0.0
    turn: float = 0.0
    pitch: float = 0.0
    jump: bool = False
    crouch: bool = False
    attack: bool = False
    use: bool = False

    def set_move(self, target: float) -> None:
        """A ``move`` command: ramp towards ``target`` from the next tick."""
        if target != self.move_target:
            self.move_target = target
            self.move_ticks = 0

    def ramp_move(self) -> None:
        """One tick of the ramp."""
        self.move_ticks += 1
        if self.move_ticks <= INERTIA_TICKS:
            self.move += (self.move_target - self.move) * self.move_ticks / INERTIA_TICKS
        else:
            self.move = self.move_target


@dataclass
class Player:
    """Everything about the agent the world tracks."""

    name: str
    body: Body
    yaw: float = 0.0
    pitch: float = 0.0
    controls: Controls = field(default_factory=Controls)
    inventory: Inventory = field(default_factory=Inventory)
    crafting: CraftState = field(default_factory=CraftState)
    health: float = 20.0
    food: int = 20
    saturation: float = 5.0
    exhaustion: float = 0.0
    air: int = MAX_AIR
    xp: int = 0
    alive: bool = True
    fire_ticks: int = 0
    regen_timer: int = 0
    distance: float = 0.0
    time_alive: int = 0
    damage_taken: float = 0.0
    damage_dealt: float = 0.0
    mobs_killed: int = 0
    # Mining and using.
    dig_target: Optional[tuple[int, int, int]] = None
    dig_progress: float = 0.0
    attack_cooldown: int = 0
    use_ticks: int = 0
    use_was_down: bool = False
    death_cause: str = ""
    creative: bool = False  # Creative mode: no damage but the void's, no hunger

    @property
    def eye(self) -> tuple[float, float, float]:
        """Eye position (1.62 above the feet; 1.54 when crouching)."""
        b = self.body
        return b.x, b.y + (1.54 if self.controls.crouch else 1.62), b.z

    def look(self) -> tuple[float, float, float]:
        """Unit look vector from yaw and pitch (yaw 0 faces south, +z; pitch > 0 down)."""
        yr, pr = math.radians(self.yaw), math.radians(self.pitch)
        cp = math.cos(pr)
        return -math.sin(yr) * cp, -math.sin(pr), math.cos(yr) * cp

    def hurt(self, amount: float, cause: str) -> None:
        """Take damage; dying records the cause."""
        if not self.alive or amount <= 0 or (self.creative and cause != VOID):
            return
        self.health -= amount
        self.damage_taken += amount
        self.exhaustion += EXHAUSTION["damage"]
        if self.health <= 0:
            self.health = 0.0
            self.alive = False
            self.death_cause = cause

    def eat(self, food: int, saturation: float) -> None:
        """Eat a food item's points (saturation capped by the food level)."""
        self.food = min(20, self.food + food)
        self.saturation = min(float(self.food), self.saturation + saturation)

    def vitals_tick(self, *, head_in_water: bool, in_lava: bool, in_water: bool) -> None:
        """One tick of hunger, regeneration, starvation, air, lava and fire."""
        self.time_alive += 1
        if self.creative:
            self.exhaustion = 0.0
        while self.exhaustion >= 4.0:
            self.exhaustion -= 4.0
            if self.saturation > 0:
                self.saturation = max(0.0, self.saturation - 1.0)
            else:
                self.food = max(0, self.food - 1)
        self.regen_timer += 1
        if self.regen_timer >= 80:
            self.regen_timer = 0
            if self.food >= 18 and self.health < 20:
                self.health = min(20.0, self.health + 1.0)
                self.exhaustion += EXHAUSTION["regen"]
            elif self.food == 0 and self.health > 1:
                self.hurt(1.0, "starved")
        if head_in_water:
            self.air -= 1
            if self.air <= -20:
                self.air = 0
                self.hurt(2.0, "drowned")
        else:
            self.air = MAX_AIR
        if in_lava:
            self.fire_ticks = 300
            if self.time_alive % 10 == 0:
                self.hurt(4.0, "tried to swim in lava")
        elif in_water:
            self.fire_ticks = 0
        if self.fire_ticks > 0:
            self.fire_ticks -= 1
            if self.fire_ticks % 20 == 0 and not in_lava:
                self.hurt(1.0, "burned to death")

    def land(self) -> None:
        """Landing after a fall: damage ``ceil(fall - 3)``."""
        dmg = math.ceil(self.body.fall_distance - 3.0)
        self.body.fall_distance = 0.0
        if dmg > 0:
            self.hurt(float(dmg), "fell from a high place")
