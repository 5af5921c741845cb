"""Malmo's schema (``Mission.xsd`` 0.37) for an ``<AgentSection>``'s start and handlers,
as ``xsd_elements`` rules: ``AgentStart`` (placement, inventory), the command handlers
and the verbs each may name, the observation producers, the reward producers and the
quit producers. ``AGENT_HANDLERS`` is what ``<AgentHandlers>`` may hold, in any order.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Optional

from minecraft.malmo.xsd_elements import (
    DESC,
    DIM,
    EMPTY,
    POS,
    Rule,
    all_of,
    el,
    many,
    one,
    opt,
    seq,
    text,
)
from minecraft.malmo.xsd_types import (
    BLOCK_LIST,
    BLOCK_OR_ITEM,
    BLOCK_OR_ITEM_LIST,
    BOOL,
    COLOUR,
    COLOUR_LIST,
    DECIMAL,
    INT,
    MOB_LIST,
    STRING,
    VARIANT,
    VARIANT_LIST,
    Check,
    decimal_range,
    hex3,
    int_range,
    list_of,
    one_of,
    xml_name,
)

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
