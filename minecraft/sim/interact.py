"""What the agent's hands do: the crosshair target, attacking (digging with Minecraft's
break times, hitting animals) and using (eating, placing blocks)."""

from __future__ import annotations

import math
from typing import Optional

from minecraft import blocks as B
from minecraft.sim.entities import MOBS, Mob
from minecraft.sim.player import EXHAUSTION
from minecraft.sim.raycast import REACH, Hit, cast_block, ray_box
from minecraft.sim.state import WorldState


def target(world: WorldState, max_dist: float = REACH, *, items: bool = False) -> Optional[Hit]:
    """What the crosshair hits within ``max_dist``: the nearest block or animal, and with
    ``items`` also dropped items (Malmo's ray observation sees them; hands do not)."""
    p = world.player
    eye, d = p.eye, p.look()
    hit = cast_block(world.blocks, world.x0, world.z0, eye, d, max_dist)
    best = hit.distance if hit is not None else max_dist
    bodies = [("entity", i, m.body) for i, m in enumerate(world.mobs)]
    if items:
        bodies += [("item", i, it.body) for i, it in enumerate(world.items)]
    for kind, i, mb in bodies:
        if abs(mb.x - eye[0]) > max_dist + 1 or abs(mb.z - eye[2]) > max_dist + 1:
            continue
        w = mb.half_width
        t = ray_box(eye, d, (mb.x - w, mb.y, mb.z - w, mb.x + w, mb.y + mb.height, mb.z + w))
        if t is not None and t < best:
            best = t
            hit = Hit(kind, eye[0] + d[0] * t, eye[1] + d[1] * t, eye[2] + d[2] * t, t,
                      entity=i)  # fmt: skip
    return hit


def attack_and_use(world: WorldState) -> None:
    """Per-tick effect of the held ``attack`` and ``use`` states (continuous commands)."""
    p, c = world.player, world.player.controls
    if p.attack_cooldown > 0:
        p.attack_cooldown -= 1
    if c.attack:
        attack(world, instant=False)
    else:
        p.dig_target, p.dig_progress = None, 0.0
    if c.use:
        use(world, hold=True)
    else:
        p.use_ticks = 0
    p.use_was_down = c.use


def attack(world: WorldState, *, instant: bool) -> None:
    """Hit what the crosshair targets: damage an animal or dig a block."""
    p = world.player
    hit = target(world)
    if hit is None:
        p.dig_target, p.dig_progress = None, 0.0
        return
    if hit.kind == "entity":
        p.dig_target, p.dig_progress = None, 0.0
        if p.attack_cooldown == 0 or instant:
            hit_mob(world, world.mobs[hit.entity])
        return
    arena = world.build_battle
    if arena is not None and arena.protects(hit.cell):
        p.dig_target, p.dig_progress = None, 0.0  # the goal structure cannot be broken
        return
    block = world.get(*hit.cell)
    held = p.inventory.held()
    if instant or p.creative:
        if B.BLOCKS[block].hardness != math.inf:
            break_block(world, hit.cell)
        return
    if p.dig_target != hit.cell:
        p.dig_target, p.dig_progress = hit.cell, 0.0
    p.dig_progress += B.break_progress_per_tick(block, held)
    if p.dig_progress >= 1.0 - 1e-9:
        break_block(world, hit.cell)
        p.dig_target, p.dig_progress = None, 0.0


def hit_mob(world: WorldState, mob: Mob) -> None:
    p = world.player
    tool = B.TOOLS.get(p.inventory.held() or "")
    dmg = tool.damage if tool is not None else 1.0
    p.attack_cooldown = 10
    p.exhaustion += EXHAUSTION["attack"]
    p.damage_dealt += dmg
    world.rules.damaged(world, mob.name, dmg)
    mob.health -= dmg
    mob.hurt_timer = 60
    mob.body.vy = 0.3
    if tool is not None:
        p.inventory.wear_held(1 if tool.kind == "sword" else 2)
    if mob.health <= 0:
        world.mobs.remove(mob)
        p.mobs_killed += 1
        p.xp += world.rng.randint(1, 3)
        meat = MOBS[mob.name][3]
        world.drop(meat, world.rng.randint(1, 3), mob.body.x, mob.body.y + 0.5, mob.body.z)


def break_block(world: WorldState, cell: tuple[int, int, int]) -> None:
    """Break a block: drops if the held tool can harvest it, wears the tool."""
    p = world.player
    block = world.get(*cell)
    if block == B.AIR or B.BLOCKS[block].hardness == math.inf:
        return
    held = p.inventory.held()
    info = B.BLOCKS[block]
    world.set(*cell, B.AIR)
    if world.build_battle is not None:
        world.build_battle.changed(cell, B.AIR)
    if p.creative:
        return  # nothing drops, tools do not wear
    p.exhaustion += EXHAUSTION["break"]
    cx, cy, cz = cell[0] + 0.5, cell[1] + 0.25, cell[2] + 0.5
    if B.can_harvest(block, held):
        drop, n = info.drop, info.drop_count
        if info.name == "gravel" and world.rng.random() < 0.1:
            drop = "flint"
        if info.name == "leaves" and world.rng.random() < 0.05:
            drop, n = "apple", 1
        world.drop(drop, n, cx, cy, cz)
    if held in B.TOOLS and info.hardness > 0:
        p.inventory.wear_held(1 if B.TOOLS[held].kind != "sword" else 2)


def use(world: WorldState, *, hold: bool) -> None:
    """Right click: eat held food (after 32 ticks when holding), else place a block."""
    p = world.player
    held = p.inventory.held()
    if held in B.FOOD and p.food < 20:
        p.use_ticks += 1
        if not hold or p.use_ticks >= 32:
            p.use_ticks = 0
            p.inventory.remove_selected_one()
            p.eat(*B.FOOD[held])
        return
    if hold and p.use_was_down:
        return  # one placement per press
    if held not in B.PLACEABLE:
        return
    hit = target(world)
    if hit is None or hit.kind != "block":
        return
    x, y, z = (a + n for a, n in zip(hit.cell, hit.normal, strict=True))
    if B.SOLID[world.get(x, y, z)] or world.get(x, y, z) == B.BEDROCK:
        return
    arena = world.build_battle
    if arena is not None and arena.protects((x, y, z)):
        return
    for body in [p.body] + [o.body for o in world.others] + [m.body for m in world.mobs]:
        w = body.half_width
        if (x < body.x + w and x + 1 > body.x - w and z < body.z + w and z + 1 > body.z - w
                and y < body.y + body.height and y + 1 > body.y):  # fmt: skip
            return
    # Malmo's RewardForDiscardingItem counts the held stack, whole, when a block is placed.
    world.lost(held, p.inventory.slots[p.inventory.selected].count)  # type: ignore[union-attr]
    world.set(x, y, z, B.ID[held])
    if arena is not None:
        arena.changed((x, y, z), B.ID[held])
    if not p.creative:  # a Creative player's stack is not used up
        p.inventory.remove_selected_one()
