"""Apply one Malmo command string (``"move 0.5"``, ``"craft planks"``, ``"hotbar.2 1"``) to
the world at the start of a tick, as Malmo's command handlers do.

The verb is lower-cased (``Move 1`` moves) and offered to the mission's handlers in XML
order; the first one whose allow/deny list lets the verb through and that accepts the
parameter handles it. A command no handler takes is ignored and counted. Handled
commands feed RewardForSendingCommand, chat rewards, command quotas and
ObservationFromRecentCommands. Parameters follow Malmo: ``jump``/``crouch`` are on only
for exactly ``1``; ``attack``/``use`` take ``1`` (press) or ``0`` (release) and nothing
else; discrete ``movenorth`` and friends ignore their parameter; ``move``, ``turn`` and
``look`` use only the sign of theirs.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from minecraft.malmo.mission import Handler
from minecraft.sim import crafting, interact
from minecraft.sim.state import WorldState


def apply(world: WorldState, command: str) -> None:
    """Run one command (unhandled, disallowed or malformed ones are ignored and counted)."""
    command = command.rstrip()
    if not command:
        return
    verb, _, parameter = command.partition(" ")
    verb = verb.lower()
    for h in world.mission.handlers:
        if not h.accepts(verb):
            continue
        run = _KINDS.get(h.kind)
        if run is None:
            continue  # a handler the simulator refuses (missions using it never start)
        try:
            handled = run(world, h, verb, parameter)
        except (ValueError, IndexError):
            break  # Malmo: a NumberFormatException ends the command's handling
        if handled:
            world.recent_commands.append(f"{verb} {parameter}")
            world.rules.handled(world, verb, parameter)
            return
    world.ignored_commands += 1


def _number(parameter: str) -> float:
    v = float(parameter)
    if not math.isfinite(v):
        raise ValueError("not finite")
    return v


def _clamp(v: float) -> float:
    return max(-1.0, min(1.0, v))


def _continuous(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    c = world.player.controls
    if verb in ("attack", "use"):
        if parameter not in ("0", "1"):
            return False  # Malmo's key handler takes only 1 (press) and 0 (release)
        setattr(c, verb, parameter == "1")
    elif verb == "move":
        c.set_move(_clamp(_number(parameter)))
    elif verb in ("strafe", "turn", "pitch"):
        setattr(c, verb, _clamp(_number(parameter)))
    else:  # jump, crouch: on for exactly "1", off for anything else
        setattr(c, verb, parameter.lower() == "1")
    return True


_CARDINAL = {"north": (0, -1), "south": (0, 1), "east": (1, 0), "west": (-1, 0)}


def _java_mod(a: int, n: int) -> int:
    return int(math.fmod(a, n))


def _direction(yaw: float) -> int:
    """Malmo's getDirectionFromYaw, Java arithmetic and all (0 +z, 1 -x, 2 -z, 3 +x)."""
    return _java_mod(int((yaw + 45.0) / 90.0) + 4, 4)


_FORWARD = {0: (0, 1), 1: (-1, 0), 2: (0, -1), 3: (1, 0)}


def _sign(parameter: str) -> int:
    v = _number(parameter)
    return (v > 0) - (v < 0)


def _step(world: WorldState, dx: int, dz: int, jump: bool) -> None:
    b = world.player.body
    nx, nz = math.floor(b.x) + dx + 0.5, math.floor(b.z) + dz + 0.5
    if (dx or dz) and not world.space.body_solid(b, nx, b.y, nz):
        b.x, b.z = nx, nz
    elif jump and not world.space.body_solid(b, nx, math.floor(b.y) + 1.0, nz):
        b.x, b.y, b.z = nx, math.floor(b.y) + 1.0, nz


def _discrete(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    p = world.player
    if verb in ("turn", "look") and not parameter:
        return False
    if verb == "turn":
        d = _java_mod(_direction(p.yaw) + _sign(parameter) + 4, 4)
        p.yaw = 90.0 * d
        return True
    if verb == "look":
        p.pitch = max(-90.0, min(90.0, p.pitch + 45.0 * _sign(parameter)))
        return True
    if verb == "attack":
        hit = interact.target(world)
        if hit is not None and hit.kind == "block":
            interact.attack(world, instant=True)
        return True
    if verb in ("use", "jumpuse"):
        if verb == "jumpuse":
            _step(world, 0, 0, True)
        interact.use(world, hold=False)
        return True
    jump = verb.startswith("jump")
    base = verb[4:] if jump else verb
    dx = dz = 0
    if base.removeprefix("move") in _CARDINAL:
        dx, dz = _CARDINAL[base.removeprefix("move")]
    elif base in ("move", "strafe"):
        if not parameter:
            return False
        direction = _direction(p.yaw) + (1 if base == "strafe" else 0)
        fx, fz = _FORWARD.get(_java_mod(direction, 4), (0, 0))
        s = _sign(parameter)
        dx, dz = fx * s, fz * s
    if not (dx or dz or jump):
        return False  # Malmo handles a discrete move only when it moves
    _step(world, dx, dz, jump)
    return True


def _absolute(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    p, b = world.player, world.player.body
    if verb == "tp":
        coords = parameter.split(" ")
        if len(coords) != 3:
            return False
        b.x, b.y, b.z = (_number(a) for a in coords)
        b.vx = b.vy = b.vz = b.fall_distance = 0.0
    elif verb in ("tpx", "tpy", "tpz"):
        setattr(b, verb[-1], _number(parameter))
        b.fall_distance = 0.0
    elif verb == "setyaw":
        p.yaw = _number(parameter)  # not wrapped, as Malmo
    elif verb == "setpitch":
        p.pitch = max(-90.0, min(90.0, _number(parameter)))
    return True


def _slot(arg: str) -> int:
    name, _, index = arg.rpartition(":")
    if name not in ("", "inventory"):
        raise ValueError(f"container {name!r} is not simulated")
    return int(index)


def _inventory(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    p = world.player
    inv = p.inventory
    if verb.startswith("hotbar."):
        if parameter not in ("0", "1"):
            return False  # a key: 1 presses (selects), 0 releases
        if parameter == "1":
            inv.selected = int(verb.split(".")[1]) - 1
    elif verb in ("swapinventoryitems", "combineinventoryitems"):
        args = parameter.split(" ")
        if len(args) != 2:
            return False
        a, b = _slot(args[0]), _slot(args[1])
        inv.swap(a, b) if verb == "swapinventoryitems" else inv.combine(a, b)
    elif verb == "discardcurrentitem":
        item = inv.held()
        if item is not None:
            inv.remove_selected_one()  # Malmo drops one item, not the stack
            x, y, z = p.eye
            d = p.look()
            world.drop(item, 1, x + d[0], y - 0.3, z + d[2], delay=40)
            world.lost(item, 1)
    return True


def _craft(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    item = parameter.split(" ")[0].removeprefix("minecraft:")
    inv = world.player.inventory
    before = inv.count(item)
    ok, why, used = crafting.craft(inv, world.player.crafting, item)
    world.craft_log.append(f"craft {item}: " + ("ok" if ok else why))
    if ok:
        for name, n in used:
            world.lost(name, n)
        world.collected(item, inv.count(item) - before)
    return True


def _quit(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    world.chat(world.player.name, "Quitting mission")
    world.request_quit("agent quit", h.description)
    return True


def _chat(world: WorldState, h: Handler, verb: str, parameter: str) -> bool:
    world.chat(world.player.name, parameter)
    return True


_KINDS: dict[str, Callable[[WorldState, Handler, str, str], bool]] = {
    "ContinuousMovement": _continuous,
    "DiscreteMovement": _discrete,
    "AbsoluteMovement": _absolute,
    "Inventory": _inventory,
    "SimpleCraft": _craft,
    "MissionQuit": _quit,
    "Chat": _chat,
}
