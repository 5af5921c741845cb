"""Malmo's mission schema as a check: refuse what Malmo's ``Mission.xsd`` refuses.

Malmo unmarshals every ``<MissionInit>`` against its XML schema (version 0.37) and
answers 0 when that fails (``MALMOERROR...``), or when ``PlatformVersion`` is not its own
(``MALMOERRORVERSIONMISMATCH``). This module states the schema's rules as Python data,
element by element, and checks a parsed mission against them: element names in Malmo's
namespace, order where the schema gives a sequence (``About``, ``ModSettings``,
``ServerSection``, ``AgentSection``; a world generator before decorators before
server quit producers; ``Name``, ``AgentStart``, ``AgentHandlers``), any order where it
gives ``xs:all`` (the handlers), required elements and attributes, attribute types and
ranges, and Minecraft names (blocks, items, entities). The first violation is raised
as ``SchemaError`` naming the element and what was wrong.

The content of decorators the simulator does not implement (``MazeDecorator``,
``ClassroomDecorator``...) is not checked below their own element.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Optional

from actors.minecraft import names as N
from actors.minecraft.malmo.xsd_types import (
    BLOCK,
    BLOCK_LIST,
    BLOCK_OR_ITEM,
    BLOCK_OR_ITEM_LIST,
    BOOL,
    COLOUR,
    COLOUR_LIST,
    DECIMAL,
    FACING,
    INT,
    MOB_LIST,
    STRING,
    VARIANT,
    VARIANT_LIST,
    Check,
    decimal_range,
    did_you_mean,
    hex3,
    int_range,
    list_of,
    one_of,
    string,
    xml_name,
)

NS = "http://ProjectMalmo.microsoft.com"
PLATFORM_VERSION = "0.37.0"  # the Malmo mod version MalmoEnv 0.37.0 runs


class SchemaError(ValueError):
    """The mission breaks Malmo's schema; the message names the element."""


# ------------------------------------------------------------------ element rules
@dataclass(frozen=True)
class Rule:
    """What one element may hold.

    Attributes:
        attrs: attribute name -> value check (undeclared attributes are refused).
        required: attributes that must be present.
        kind: ``empty``, ``text`` (checked by ``text``), ``seq`` (``particles`` in
            order), ``all`` (``children`` in any order, each at most once, ``needed``
            ones present) or ``any`` (not checked below this element).
        particles: for ``seq``: (child name -> rule, min, max or None) in order; a
            particle with several names is a choice.
        children: for ``all``: child name -> rule.
        needed: for ``all``: children that must be present.
        text: for ``text``: the value check.
    """

    attrs: Mapping[str, Check] = field(default_factory=dict)
    required: frozenset[str] = frozenset()
    kind: str = "empty"
    particles: tuple[tuple[Mapping[str, Rule], int, Optional[int]], ...] = ()
    children: Mapping[str, Rule] = field(default_factory=dict)
    needed: frozenset[str] = frozenset()
    text: Check = string


Particle = tuple[Mapping[str, Rule], int, Optional[int]]


def el(attrs: Optional[Mapping[str, Check]] = None, req: str = "") -> Rule:
    """An element without content; ``attrs`` its attributes, ``req`` the required ones."""
    return Rule(dict(attrs or {}), frozenset(req.split()))


def text(check: Check) -> Rule:
    """An element holding a value, checked by ``check``."""
    return Rule(kind="text", text=check)


def seq(*particles: Particle, attrs: Optional[Mapping[str, Check]] = None, req: str = "") -> Rule:
    """An element whose children come in the order of ``particles``."""
    return Rule(dict(attrs or {}), frozenset(req.split()), "seq", particles)


def all_of(
    children: Mapping[str, Rule], needed: str = "", attrs: Optional[Mapping[str, Check]] = None
) -> Rule:
    """An element whose children come in any order, each at most once."""
    return Rule(
        dict(attrs or {}), kind="all", children=dict(children), needed=frozenset(needed.split())
    )


def one(name: str, rule: Rule) -> Particle:
    return ({name: rule}, 1, 1)


def opt(name: str, rule: Rule) -> Particle:
    return ({name: rule}, 0, 1)


def many(rules: Mapping[str, Rule], lo: int = 1) -> Particle:
    return (rules, lo, None)


ANY = Rule(kind="any")
EMPTY = Rule()
POS = {"x": DECIMAL, "y": DECIMAL, "z": DECIMAL}
INT_POS = {"x": INT, "y": INT, "z": INT}
DIM = {"dimension": int_range(0)}
DESC = {"description": STRING}

# ----------------------------------------------------------- agent start
_INVENTORY_OBJECT = el(
    {"slot": int_range(0, 39), "type": BLOCK_OR_ITEM, "variant": VARIANT, "colour": COLOUR,
     "quantity": int_range(1, 64)},
    "slot type",
)  # fmt: skip
_INVENTORY = seq(
    many({n: _INVENTORY_OBJECT for n in ("InventoryObject", "InventoryItem", "InventoryBlock")}, 0)
)
AGENT_START = all_of(
    {
        "Placement": el(
            POS | {"yaw": decimal_range(-360, 360), "pitch": decimal_range(-90, 90)}, "x y z"
        ),
        "Inventory": _INVENTORY,
        "EnderBoxInventory": _INVENTORY,
    }
)

# ------------------------------------------------------------- commands
CONTINUOUS_VERBS = ("move", "strafe", "pitch", "turn", "jump", "crouch", "attack", "use")
ABSOLUTE_VERBS = ("tpx", "tpy", "tpz", "tp", "setYaw", "setPitch")
DISCRETE_VERBS = (
    "move jumpmove strafe jumpstrafe turn movenorth moveeast movesouth movewest jumpnorth "
    "jumpeast jumpsouth jumpwest jump look attack use jumpuse".split()
)
INVENTORY_VERBS = ("swapInventoryItems", "combineInventoryItems", "discardCurrentItem") + tuple(
    f"hotbar.{i}" for i in range(1, 10)
)
HUMAN_VERBS = (
    "forward left back right jump sneak sprint inventory swapHands drop use attack pickItem".split()
    + [f"hotbar.{i}" for i in range(1, 10)]
    + ["moveMouse"]
)
# Command handler element -> the verbs its ModifierList may name.
COMMAND_VERBS: dict[str, tuple[str, ...]] = {
    "ContinuousMovementCommands": CONTINUOUS_VERBS,
    "AbsoluteMovementCommands": ABSOLUTE_VERBS,
    "DiscreteMovementCommands": tuple(DISCRETE_VERBS),
    "InventoryCommands": INVENTORY_VERBS,
    "ChatCommands": ("chat",),
    "SimpleCraftCommands": ("craft",),
    "NearbyCraftCommands": ("craftNearby",),
    "NearbySmeltCommands": ("smeltNearby",),
    "PlaceCommands": ("place",),
    "MissionQuitCommands": ("quit",),
    "HumanLevelCommands": tuple(HUMAN_VERBS),
}
ALL_VERBS = frozenset(v for verbs in COMMAND_VERBS.values() for v in verbs)


def _commands(name: str, extra: Optional[Mapping[str, Rule]] = None, **attrs: Check) -> Rule:
    modifiers = seq(
        many({"command": text(one_of(COMMAND_VERBS[name], f"a {name} verb"))}, 0),
        attrs={"type": one_of(("deny-list", "allow-list"), "deny-list or allow-list")},
    )
    return all_of({"ModifierList": modifiers} | dict(extra or {}), attrs=attrs)


_COMMANDS: dict[str, Rule] = {
    "ContinuousMovementCommands": _commands("ContinuousMovementCommands", turnSpeedDegs=DECIMAL),
    "AbsoluteMovementCommands": _commands("AbsoluteMovementCommands"),
    "DiscreteMovementCommands": _commands("DiscreteMovementCommands", autoFall=BOOL, autoJump=BOOL),
    "InventoryCommands": _commands("InventoryCommands"),
    "ChatCommands": _commands("ChatCommands"),
    "SimpleCraftCommands": _commands("SimpleCraftCommands", {"ViewToCraft": text(BOOL)}),
    "NearbyCraftCommands": _commands("NearbyCraftCommands", {"ViewToCraft": text(BOOL)}),
    "NearbySmeltCommands": _commands("NearbySmeltCommands", {"ViewToSmelt": text(BOOL)}),
    "PlaceCommands": _commands("PlaceCommands"),
    "MissionQuitCommands": _commands("MissionQuitCommands", quitDescription=STRING),
    "HumanLevelCommands": _commands("HumanLevelCommands"),
}
_TURN_BASED = all_of(
    {k: _COMMANDS[k] for k in ("AbsoluteMovementCommands", "DiscreteMovementCommands",
                               "InventoryCommands", "ChatCommands", "SimpleCraftCommands",
                               "MissionQuitCommands")},
    attrs={"requestedPosition": int_range(0)},
)  # fmt: skip

# --------------------------------------------------------- observations
_SIZE = (one("Width", text(INT)), one("Height", text(INT)))
_POS_EL = el(POS, "x y z")
_OBSERVATIONS: dict[str, Rule] = {
    name: EMPTY
    for name in (
        "ObservationFromRecentCommands", "ObservationFromHotBar", "ObservationFromFullStats",
        "ObservationFromDiscreteCell", "ObservationFromChat", "ObservationFromTurnScheduler",
        "ObservationFromHuman", "ObservationFromSystem", "ObservationFromCompass",
    )
}  # fmt: skip
_OBSERVATIONS |= {
    "ObservationFromFullInventory": el({"flat": BOOL}),
    "ObservationFromRay": el({"includeNBT": BOOL}),
    "ObservationFromSubgoalPositionList": seq(
        many({"Point": el(POS | {"tolerance": DECIMAL} | DESC, "x y z")})
    ),
    "ObservationFromDistance": seq(many({"Marker": el(POS | {"name": xml_name}, "x y z name")})),
    "ObservationFromGrid": seq(
        many(
            {
                "Grid": seq(
                    one("min", _POS_EL),
                    one("max", _POS_EL),
                    attrs={"name": xml_name, "absoluteCoords": BOOL},
                    req="name",
                )
            }
        )
    ),  # fmt: skip
    "ObservationFromNearbyEntities": seq(
        many(
            {
                "Range": el(
                    {
                        "name": xml_name,
                        "xrange": DECIMAL,
                        "yrange": DECIMAL,
                        "zrange": DECIMAL,
                        "update_frequency": INT,
                    },
                    "name xrange yrange zrange",
                )
            }
        )
    ),  # fmt: skip
    "VideoProducer": seq(
        *_SIZE,
        opt(
            "DepthScaling",
            el({"min": decimal_range(0, 1), "max": decimal_range(0, 1), "autoscale": BOOL}),
        ),
        attrs={"want_depth": BOOL, "viewpoint": int_range(0, 2)},
    ),
    "DepthProducer": seq(*_SIZE),
    "LuminanceProducer": seq(*_SIZE),
    "ColourMapProducer": seq(
        *_SIZE,
        many({"ColourSpec": el({"type": MOB_LIST, "colour": hex3}, "type colour")}, 0),
        attrs={"skyColour": hex3},
    ),
}

# --------------------------------------------------------- rewards, quits
_BLOCK_SPEC = {"type": BLOCK_LIST, "amount": INT, "variant": VARIANT_LIST, "colour": COLOUR_LIST}
_ITEM_SPEC = _BLOCK_SPEC | {"type": BLOCK_OR_ITEM_LIST}
_REWARD = {"reward": DECIMAL, "distribution": STRING}


def _entries(
    child: str, attrs: Mapping[str, Check], req: str, own: Optional[Mapping[str, Check]] = None,
    lo: int = 1,
) -> Rule:  # fmt: skip
    """Repeated ``child`` elements (``lo`` or more); ``own``: the parent's attributes."""
    return seq(many({child: el(attrs, req)}, lo), attrs=dict(own or {}))


_ITEM_REWARD = _entries("Item", _ITEM_SPEC | _REWARD, "type reward", DIM)
_SPARSE_ITEM_REWARD = _entries("Item", _ITEM_SPEC | _REWARD, "type reward", DIM | {"Sparse": BOOL})
_ITEM_QUIT = _entries("Item", _ITEM_SPEC | DESC, "type")
_MOB = {"type": MOB_LIST, "description": STRING, "global": BOOL}
_REWARDS: dict[str, Rule] = {
    "RewardForTouchingBlockType": _entries(
        "Block",
        _BLOCK_SPEC
        | _REWARD
        | {
            "behaviour": one_of(
                ("onceOnly", "oncePerBlock", "oncePerTimeSpan", "constant"), "a touch behaviour"
            ),
            "cooldownInMs": DECIMAL,
        },
        "type reward",
        DIM,
    ),  # fmt: skip
    "RewardForSendingCommand": el(_REWARD | DIM),
    "RewardForSendingMatchingChatMessage": _entries(
        "ChatMatch", DESC | _REWARD | {"regex": STRING}, "description reward regex", DIM
    ),
    "RewardForCollectingItem": _ITEM_REWARD,
    "RewardForPossessingItem": _SPARSE_ITEM_REWARD,
    "RewardForCraftingItem": _SPARSE_ITEM_REWARD,
    "RewardForSmeltingItem": _SPARSE_ITEM_REWARD,
    "RewardForDiscardingItem": _ITEM_REWARD,
    "RewardForReachingPosition": _entries(
        "Marker",
        POS | _REWARD | {"tolerance": DECIMAL, "oneshot": BOOL},
        "x y z reward tolerance",
        DIM,
    ),  # fmt: skip
    "RewardForMissionEnd": _entries(
        "Reward",
        _REWARD | DESC,
        "reward description",
        DIM | {"rewardForDeath": DECIMAL, "rewardForDeathDistribution": STRING},
    ),  # fmt: skip
    "RewardForStructureCopying": all_of(
        {
            "RewardDensity": text(one_of(("PER_BLOCK", "MISSION_END"), "a reward density")),
            "AddQuitProducer": el(DESC),
        },
        "RewardDensity",
        attrs=DIM
        | {"rewardScale": DECIMAL, "rewardDistribution": STRING, "rewardForCompletion": DECIMAL},
    ),  # fmt: skip
    "RewardForTimeTaken": el(
        DIM
        | {
            "initialReward": DECIMAL,
            "delta": DECIMAL,
            "rewardDistribution": STRING,
            "density": one_of(
                ("PER_TICK", "PER_TICK_ACCUMULATED", "MISSION_END"), "a time reward density"
            ),
        },
        "initialReward delta density",
    ),  # fmt: skip
    "RewardForCatchingMob": _entries("Mob", _MOB | _REWARD | {"oneshot": BOOL}, "type reward", DIM),
    "RewardForDamagingEntity": _entries("Mob", {"type": MOB_LIST} | _REWARD, "type reward", DIM),
}
_QUITS: dict[str, Rule] = {
    "AgentQuitFromTimeUp": el({"timeLimitMs": DECIMAL} | DESC, "timeLimitMs"),
    "AgentQuitFromReachingPosition": _entries(
        "Marker", POS | {"tolerance": DECIMAL} | DESC, "x y z"
    ),
    "AgentQuitFromTouchingBlockType": _entries("Block", _BLOCK_SPEC | DESC, "type"),
    "AgentQuitFromCollectingItem": _ITEM_QUIT,
    "AgentQuitFromPossessingItem": _ITEM_QUIT,
    "AgentQuitFromCraftingItem": _ITEM_QUIT,
    "AgentQuitFromSmeltingItem": _ITEM_QUIT,
    "AgentQuitFromReachingCommandQuota": _entries(
        "Quota",
        {"commands": list_of(ALL_VERBS, "a Malmo command verb"), "quota": INT} | DESC,
        "commands quota",
        {"total": INT, "description": STRING},
        lo=0,
    ),  # fmt: skip
    "AgentQuitFromCatchingMob": _entries("Mob", _MOB, "type"),
}
AGENT_HANDLERS: dict[str, Rule] = (
    _OBSERVATIONS | _REWARDS | _COMMANDS | {"TurnBasedCommands": _TURN_BASED} | _QUITS
)

# ------------------------------------------------------------------ server
_BLOCK_BASED = {"type": BLOCK, "variant": VARIANT, "colour": COLOUR, "face": FACING}
_CORNERS = {k: INT for k in ("x1", "y1", "z1", "x2", "y2", "z2")}
DRAW_OPS: dict[str, Rule] = {
    "DrawObjectType": EMPTY,
    "DrawBlock": el(_BLOCK_BASED | INT_POS, "type x y z"),
    "DrawCuboid": el(_BLOCK_BASED | _CORNERS, "type x1 y1 z1 x2 y2 z2"),
    "DrawSphere": el(_BLOCK_BASED | INT_POS | {"radius": INT}, "type x y z radius"),
    "DrawLine": el(_BLOCK_BASED | _CORNERS | {"steptype": BLOCK}, "type x1 y1 z1 x2 y2 z2"),
    "DrawItem": el(_BLOCK_BASED | INT_POS | {"type": BLOCK_OR_ITEM}, "type x y z"),
    "DrawEntity": el(
        {
            "x": DECIMAL,
            "y": DECIMAL,
            "z": DECIMAL,
            "yaw": DECIMAL,
            "pitch": DECIMAL,
            "xVel": DECIMAL,
            "yVel": DECIMAL,
            "zVel": DECIMAL,
            "type": one_of(N.SPAWNABLE_TYPES, "a spawnable entity type"),
        },
        "type x y z",
    ),  # fmt: skip
    "DrawContainer": seq(
        many(
            {
                "Object": el(
                    {"type": BLOCK_OR_ITEM, "variant": VARIANT, "colour": COLOUR, "quantity": INT},
                    "type",
                )
            }
        ),
        attrs=_BLOCK_BASED | INT_POS | {"type": one_of(N.CONTAINER_TYPES, "a container type")},
        req="type x y z",
    ),  # fmt: skip
    "DrawSign": el(
        _BLOCK_BASED
        | INT_POS
        | {"type": one_of(N.SIGN_TYPES, "a sign type"), "rotation": INT}
        | {f"line{i}": STRING for i in range(1, 5)},
        "type x y z",
    ),  # fmt: skip
}
_RESET = {"forceReset": BOOL, "destroyAfterUse": BOOL}
GENERATORS: dict[str, Rule] = {
    "FlatWorldGenerator": el({"generatorString": STRING, "seed": STRING} | _RESET),
    "FileWorldGenerator": el({"src": STRING} | _RESET, "src"),
    "DefaultWorldGenerator": el({"seed": STRING} | _RESET),
    "BiomeGenerator": el({"biome": INT} | _RESET),
}
DECORATORS: dict[str, Rule] = {"DrawingDecorator": seq(many(DRAW_OPS))} | {
    name: ANY
    for name in (
        "AnimationDecorator", "MazeDecorator", "ClassroomDecorator", "SnakeDecorator",
        "MovingTargetDecorator", "BuildBattleDecorator", "NavigationDecorator",
    )
}  # fmt: skip
SERVER_QUITS: dict[str, Rule] = {
    "ServerQuitFromTimeUp": el({"timeLimitMs": DECIMAL} | DESC, "timeLimitMs"),
    "ServerQuitWhenAnyAgentFinishes": el(DESC),
}
SERVER_HANDLERS: dict[str, Rule] = GENERATORS | DECORATORS | SERVER_QUITS

# ----------------------------------------------------------------- mission
_INITIAL = all_of(
    {
        "Time": all_of({"StartTime": text(int_range(0, 23999)), "AllowPassageOfTime": text(BOOL)}),
        "Weather": text(one_of(("normal", "clear", "rain", "thunder"), "a weather")),
        "AllowSpawning": text(BOOL),
        "AllowedMobs": text(MOB_LIST),
    }
)
MISSION = seq(
    one("About", seq(one("Summary", text(STRING)), opt("Description", text(STRING)))),
    opt("ModSettings", all_of(
        {"MsPerTick": text(int_range(1)), "PrioritiseOffscreenRendering": text(BOOL)}
    )),
    one("ServerSection", seq(
        opt("ServerInitialConditions", _INITIAL),
        one("ServerHandlers", seq((GENERATORS, 1, 1), many(DECORATORS, 0),
                                  many(SERVER_QUITS, 0))),
    )),
    many({"AgentSection": seq(
        one("Name", text(STRING)),
        one("AgentStart", AGENT_START),
        one("AgentHandlers", all_of(AGENT_HANDLERS)),
        attrs={"mode": one_of(("Survival", "Creative", "Adventure", "Spectator"), "a game mode")},
    )}),
    attrs={"SchemaVersion": STRING},
)  # fmt: skip
_CONNECTION = seq(
    *(one(n, text(STRING)) for n in ("ClientIPAddress",)),
    *(one(n, text(INT)) for n in ("ClientMissionControlPort", "ClientCommandsPort")),
    one("AgentIPAddress", text(STRING)),
    *(
        one(n, text(INT))
        for n in ("AgentMissionControlPort", "AgentVideoPort", "AgentDepthPort",
                  "AgentLuminancePort", "AgentObservationsPort", "AgentRewardsPort",
                  "AgentColourMapPort")
    ),
)  # fmt: skip
MISSION_INIT = seq(
    one("Mission", MISSION),
    one("ExperimentUID", text(STRING)),
    opt("MinecraftServerConnection", el({"address": STRING, "port": INT}, "address port")),
    one("ClientRole", text(INT)),
    one("ClientAgentConnection", _CONNECTION),
    attrs={"SchemaVersion": STRING, "PlatformVersion": STRING},
)


# ------------------------------------------------------------------- check
def validate(root: ET.Element) -> None:
    """Check a ``<Mission>`` or ``<MissionInit>`` element against Malmo's schema.

    For a ``<MissionInit>`` the ``PlatformVersion`` attribute must also be Malmo's own
    version, as Malmo checks after the schema.

    Raises:
        SchemaError: the first violation, naming the element (``<Mission>/<About>``...).
    """
    name = _local(root, "")
    if name == "MissionInit":
        _check(root, MISSION_INIT, "<MissionInit>")
        got = root.get("PlatformVersion")
        if got != PLATFORM_VERSION:
            raise SchemaError(
                f"<MissionInit PlatformVersion={got!r}>: Malmo {PLATFORM_VERSION} refuses it "
                f"(version mismatch: got {got}, expected {PLATFORM_VERSION})"
            )
    elif name == "Mission":
        _check(root, MISSION, "<Mission>")
    else:
        raise SchemaError(f"the root element is <{name}>, not <Mission> or <MissionInit>")


def _local(e: ET.Element, where: str) -> str:
    tag = e.tag
    if not isinstance(tag, str) or not tag.startswith("{"):
        raise SchemaError(f"{where}<{tag}> is not in Malmo's namespace {NS!r} (add xmlns)")
    uri, local = tag[1:].split("}", 1)
    if uri != NS:
        raise SchemaError(f"{where}<{local}> is in namespace {uri!r}, not Malmo's {NS!r}")
    return local


def _check(e: ET.Element, rule: Rule, path: str) -> None:
    if rule.kind == "any":
        return
    for attr, value in e.attrib.items():
        if attr.startswith("{"):
            continue  # xsi:... and other namespaced attributes
        check = rule.attrs.get(attr)
        if check is None:
            raise SchemaError(
                f"{path}: attribute {attr!r} is not allowed" + did_you_mean(attr, rule.attrs)
            )
        problem = check(value)
        if problem is not None:
            raise SchemaError(f"{path}: {attr}={value!r} {problem}")
    for attr in sorted(rule.required - set(e.attrib)):
        raise SchemaError(f"{path}: required attribute {attr!r} is missing")
    kids = list(e)
    if rule.kind == "text":
        if kids:
            raise SchemaError(f"{path}: holds <{_local(kids[0], path + '/')}> but only text")
        problem = rule.text(e.text or "")
        if problem is not None:
            raise SchemaError(f"{path}: {(e.text or '').strip()!r} {problem}")
        return
    if (e.text or "").strip() or any((k.tail or "").strip() for k in kids):
        raise SchemaError(f"{path}: text is not allowed here")
    if rule.kind == "empty":
        if kids:
            raise SchemaError(f"{path}: must be empty, holds <{_local(kids[0], path + '/')}>")
    elif rule.kind == "all":
        _check_all(kids, rule, path)
    else:
        _check_seq(kids, rule, path)


def _child_path(path: str, name: str, index: int) -> str:
    return f"{path}/<{name}>" + (f"[{index}]" if index else "")


def _check_all(kids: list[ET.Element], rule: Rule, path: str) -> None:
    seen: set[str] = set()
    for k in kids:
        name = _local(k, path + "/")
        child = rule.children.get(name)
        if child is None:
            raise SchemaError(
                f"{path}: unknown element <{name}>" + did_you_mean(name, rule.children)
            )
        if name in seen:
            raise SchemaError(f"{path}: <{name}> appears twice (at most once)")
        seen.add(name)
        _check(k, child, _child_path(path, name, 0))
    for name in sorted(rule.needed - seen):
        raise SchemaError(f"{path}: required element <{name}> is missing")


def _check_seq(kids: list[ET.Element], rule: Rule, path: str) -> None:
    i = 0
    names = [_local(k, path + "/") for k in kids]
    for choices, lo, hi in rule.particles:
        count = 0
        while i < len(kids) and names[i] in choices and (hi is None or count < hi):
            _check(kids[i], choices[names[i]], _child_path(path, names[i], count))
            i, count = i + 1, count + 1
        if count < lo:
            wanted = " or ".join(f"<{n}>" for n in choices)
            found = f", found <{names[i]}>" if i < len(names) else ""
            raise SchemaError(f"{path}: expected {wanted}{found}")
    if i < len(kids):
        name = names[i]
        known = {n for choices, _, _ in rule.particles for n in choices}
        if name in known:
            raise SchemaError(f"{path}: <{name}> is out of order or repeated")
        raise SchemaError(f"{path}: unknown element <{name}>" + did_you_mean(name, known))
