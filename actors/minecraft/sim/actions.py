"""Apply one Malmo command string (``"move 0.5"``, ``"craft planks"``, ``"hotbar.2 1"``) to
the world at the start of a tick.

A command runs only if one of the mission's command handlers accepts its verb (the first
in XML order, as in Malmo); anything else is ignored and counted, as Malmo ignores
commands no handler claims. Bad arguments are ignored the same way.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from actors.minecraft import blocks as B
from actors.minecraft.sim import crafting, interact
from actors.minecraft.sim.physics import JUMP_SPEED
from actors.minecraft.sim.world import World

CRAFT_REACH = 4  # blocks: a placed crafting table or furnace this close can be used


def apply(world: World, command: str) -> None:
    """Run one command (unknown, disallowed or malformed ones are ignored and counted)."""
    parts = command.strip().split()
    if not parts:
        return
    verb, args = parts[0], parts[1:]
    handler = world.mission.handler_for(verb)
    fn = _KINDS.get(handler.kind) if handler is not None else None
    if fn is None:
        world.ignored_commands += 1
        return
    if world.mission.command_reward is not None:
        world.pending_reward += world.mission.command_reward
    try:
        fn(world, verb, args)
    except (ValueError, IndexError):
        world.ignored_commands += 1


def _value(args: list[str], default: float = 1.0) -> float:
    v = float(args[0]) if args else default
    if not math.isfinite(v):
        raise ValueError("not finite")
    return v


def _continuous(world: World, verb: str, args: list[str]) -> None:
    c = world.player.controls
    v = max(-1.0, min(1.0, _value(args)))
    if verb in ("move", "strafe", "turn", "pitch"):
        setattr(c, verb, v)
    else:  # jump, crouch, attack, use
        setattr(c, verb, v != 0.0)


_CARDINAL = {"north": (0, -1), "south": (0, 1), "east": (1, 0), "west": (-1, 0)}


def _facing(yaw: float) -> tuple[int, int]:
    q = round((yaw % 360.0) / 90.0) % 4
    return ((0, 1), (-1, 0), (0, -1), (1, 0))[q]


def _step(world: World, dx: int, dz: int, jump: bool) -> None:
    b = world.player.body
    nx, nz = math.floor(b.x) + dx + 0.5, math.floor(b.z) + dz + 0.5
    if not world.space.body_solid(b, nx, b.y, nz):
        b.x, b.z = nx, nz
    elif jump and not world.space.body_solid(b, nx, math.floor(b.y) + 1.0, nz):
        b.x, b.y, b.z = nx, math.floor(b.y) + 1.0, nz


def _discrete(world: World, verb: str, args: list[str]) -> None:
    p = world.player
    n = int(round(_value(args)))
    if verb in ("turn", "look"):
        if verb == "turn":
            p.yaw = (round(p.yaw / 90.0) * 90.0 + 90.0 * n) % 360.0
        else:
            p.pitch = max(-90.0, min(90.0, p.pitch + 45.0 * n))
        return
    if n == 0:
        return
    if verb in ("attack", "use", "jumpuse", "jump"):
        if verb in ("jump", "jumpuse") and p.body.on_ground:
            p.body.vy = JUMP_SPEED
        if verb == "attack":
            interact.attack(world, instant=True)
        elif verb in ("use", "jumpuse"):
            interact.use(world, hold=False)
        return
    jump = verb.startswith("jump")
    base = verb[4:] if jump else verb
    if base.startswith("move") and base[4:] in _CARDINAL:
        dx, dz = _CARDINAL[base[4:]]
        _step(world, dx, dz, jump)
        return
    fx, fz = _facing(p.yaw)
    sign = 1 if n > 0 else -1
    if base == "move":
        _step(world, fx * sign, fz * sign, jump)
    elif base == "strafe":  # right of facing (fx, fz) is (-fz, fx)
        _step(world, -fz * sign, fx * sign, jump)


def _absolute(world: World, verb: str, args: list[str]) -> None:
    p, b = world.player, world.player.body
    if verb == "tp":
        b.x, b.y, b.z = (float(a) for a in args[:3])
        b.vx = b.vy = b.vz = b.fall_distance = 0.0
    elif verb in ("tpx", "tpy", "tpz"):
        setattr(b, verb[-1], _value(args))
        b.fall_distance = 0.0
    elif verb == "setYaw":
        p.yaw = _value(args) % 360.0
    elif verb == "setPitch":
        p.pitch = max(-90.0, min(90.0, _value(args)))


def _slot(arg: str) -> int:
    return int(arg.rsplit(":", 1)[-1])


def _inventory(world: World, verb: str, args: list[str]) -> None:
    p = world.player
    inv = p.inventory
    if verb.startswith("hotbar."):
        if _value(args) != 0:
            inv.selected = int(verb.split(".")[1]) - 1
    elif verb == "swapInventoryItems":
        inv.swap(_slot(args[0]), _slot(args[1]))
    elif verb == "combineInventoryItems":
        inv.combine(_slot(args[0]), _slot(args[1]))
    elif verb == "discardCurrentItem":
        stack = inv.take_selected()
        if stack is not None:
            x, y, z = p.eye
            d = p.look()
            world.drop(stack.item, stack.count, x + d[0], y - 0.3, z + d[2], delay=40)


def _near(world: World, name: str) -> bool:
    b = world.player.body
    r = CRAFT_REACH
    ix, iz = math.floor(b.x) - world.x0, math.floor(b.z) - world.z0
    iy = math.floor(b.y)
    sub = world.blocks[
        max(ix - r, 0) : ix + r + 1, max(iy - r, 0) : iy + r + 2, max(iz - r, 0) : iz + r + 1
    ]
    return bool(np.any(sub == B.ID[name]))


def _craft(world: World, verb: str, args: list[str]) -> None:
    if not args:
        return
    item = args[0].removeprefix("minecraft:")
    inv = world.player.inventory
    before = inv.count(item)
    ok, why = crafting.craft(
        inv,
        world.player.crafting,
        item,
        table_near=_near(world, "crafting_table"),
        furnace_near=_near(world, "furnace"),
    )
    world.craft_log.append(f"craft {item}: " + ("ok" if ok else why))
    if ok:
        world.collected(item, inv.count(item) - before)


def _quit(world: World, verb: str, args: list[str]) -> None:
    world.end("agent quit")


def _chat(world: World, verb: str, args: list[str]) -> None:
    return None


_KINDS: dict[str, Callable[[World, str, list[str]], None]] = {
    "ContinuousMovement": _continuous,
    "DiscreteMovement": _discrete,
    "AbsoluteMovement": _absolute,
    "Inventory": _inventory,
    "SimpleCraft": _craft,
    "MissionQuit": _quit,
    "Chat": _chat,
}
