"""A mission's reward producers and agent quit producers, parsed into plain data.

Element names and defaults follow Malmo's schema (``RewardForTouchingBlockType``
behaviour ``oncePerBlock`` with a 1000 ms cooldown, ``AgentQuitFromReachingPosition``
tolerance 0.5...). What triggers each one, and when, is the simulator's business
(``minecraft.sim.rules``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Optional


@dataclass(frozen=True)
class TypedReward:
    """A reward for items, blocks or mobs of the given types (per item, or per damage
    point for RewardForDamagingEntity)."""

    types: frozenset[str]
    reward: float


@dataclass(frozen=True)
class TouchReward:
    """A RewardForTouchingBlockType ``Block``."""

    types: frozenset[str]
    reward: float
    behaviour: str = "oncePerBlock"
    cooldown_ms: float = 1000.0


@dataclass(frozen=True)
class PositionReward:
    """A RewardForReachingPosition ``Marker``."""

    x: float
    y: float
    z: float
    tolerance: float
    reward: float
    oneshot: bool = True


@dataclass(frozen=True)
class TimeReward:
    """RewardForTimeTaken: ``density`` PER_TICK, PER_TICK_ACCUMULATED or MISSION_END."""

    initial: float
    delta: float
    density: str


@dataclass(frozen=True)
class TypedQuit:
    """An agent quit on touching or collecting one of ``types``; ``description`` is the
    quit code RewardForMissionEnd matches."""

    types: frozenset[str]
    description: str = ""


@dataclass(frozen=True)
class PositionQuit:
    """An AgentQuitFromReachingPosition ``Marker``."""

    x: float
    y: float
    z: float
    tolerance: float = 0.5
    description: str = ""


@dataclass(frozen=True)
class CommandQuota:
    """An AgentQuitFromReachingCommandQuota ``Quota``: quit after ``quota`` handled
    commands whose verb is in ``verbs`` (as written: Malmo compares the lower-cased
    verb with them, so ``setYaw`` never counts)."""

    verbs: frozenset[str]
    quota: int
    description: str = ""


@dataclass(frozen=True)
class CatchRule:
    """A RewardForCatchingMob or AgentQuitFromCatchingMob ``Mob``: a mob of ``types``
    trapped anywhere (``everywhere``: the ``global`` attribute) or next to the agent."""

    types: frozenset[str]
    everywhere: bool = False
    reward: float = 0.0
    description: str = ""


@dataclass(frozen=True)
class StructureCopying:
    """RewardForStructureCopying: per block event (``PER_BLOCK``) or at the end
    (``MISSION_END``), ``scale`` per change of the copy's score, ``completion`` once when
    the copy first matches; shared out as ``distribution`` says; with ``quit`` (the
    AddQuitProducer's description) the mission ends when the copy is complete."""

    density: str = "PER_BLOCK"
    scale: float = 5.0
    completion: float = 200.0
    distribution: str = ""
    quit: Optional[str] = None


@dataclass(frozen=True)
class Rules:
    """Rewards and agent quits of one AgentSection.

    Attributes:
        collect: RewardForCollectingItem (picked up, crafted or smelted).
        discard: RewardForDiscardingItem (dropped, placed, or used up by crafting).
        touch: RewardForTouchingBlockType.
        command_reward: RewardForSendingCommand reward per handled command, or None.
        positions: RewardForReachingPosition markers.
        mission_end: RewardForMissionEnd (description, reward) cases.
        death_reward: RewardForMissionEnd ``rewardForDeath``.
        time: RewardForTimeTaken, or None.
        damage: RewardForDamagingEntity (reward per point of damage dealt).
        chat: RewardForSendingMatchingChatMessage (regex, reward).
        catch: RewardForCatchingMob.
        quit_collect: AgentQuitFromCollectingItem.
        quit_touch: AgentQuitFromTouchingBlockType.
        quit_positions: AgentQuitFromReachingPosition.
        quit_time: AgentQuitFromTimeUp (limit in game ms, description), or None.
        quota_total: AgentQuitFromReachingCommandQuota ``total`` and its description.
        quotas: its per-verb ``Quota`` entries.
        quit_catch: AgentQuitFromCatchingMob.
        copying: RewardForStructureCopying, or None.
    """

    collect: tuple[TypedReward, ...] = ()
    discard: tuple[TypedReward, ...] = ()
    touch: tuple[TouchReward, ...] = ()
    command_reward: Optional[float] = None
    positions: tuple[PositionReward, ...] = ()
    mission_end: tuple[tuple[str, float], ...] = ()
    death_reward: float = 0.0
    time: Optional[TimeReward] = None
    damage: tuple[TypedReward, ...] = ()
    chat: tuple[tuple[str, float], ...] = ()
    catch: tuple[CatchRule, ...] = ()
    quit_collect: tuple[TypedQuit, ...] = ()
    quit_touch: tuple[TypedQuit, ...] = ()
    quit_positions: tuple[PositionQuit, ...] = ()
    quit_time: Optional[tuple[float, str]] = None
    quota_total: Optional[tuple[int, str]] = None
    quotas: tuple[CommandQuota, ...] = ()
    quit_catch: tuple[CatchRule, ...] = ()
    copying: Optional[StructureCopying] = None


def _tag(e: ET.Element) -> str:
    return e.tag.rsplit("}", 1)[-1]


def finite_attr(e: ET.Element, attr: str) -> Optional[float]:
    """The attribute as a finite float, None when absent.

    Raises:
        ValueError: it is not a finite number (naming the element and attribute).
    """
    raw = e.get(attr)
    if raw is None:
        return None
    try:
        v = float(raw)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ValueError(f"<{_tag(e)}> {attr}={raw!r} is not a finite number")
    return v


def _f(e: ET.Element, attr: str, default: float = 0.0) -> float:
    v = finite_attr(e, attr)
    return default if v is None else v


def _types(e: ET.Element) -> frozenset[str]:
    return frozenset(t.removeprefix("minecraft:") for t in e.get("type", "").split())


def _bool(e: ET.Element, attr: str, default: bool) -> bool:
    raw = e.get(attr)
    return default if raw is None else raw.strip() in ("true", "1")


def parse_rules(agent_handlers: ET.Element) -> Rules:
    """The reward and quit producers among an ``<AgentHandlers>``'s children.

    Raises:
        ValueError: a number that is not finite, naming the element and attribute.
    """
    kw: dict[str, object] = {}
    for h in agent_handlers:
        t, kids = _tag(h), list(h)
        if t in ("RewardForCollectingItem", "RewardForDiscardingItem", "RewardForDamagingEntity"):
            key = {"RewardForCollectingItem": "collect", "RewardForDiscardingItem": "discard",
                   "RewardForDamagingEntity": "damage"}[t]  # fmt: skip
            kw[key] = tuple(TypedReward(_types(i), _f(i, "reward")) for i in kids)
        elif t == "RewardForTouchingBlockType":
            kw["touch"] = tuple(
                TouchReward(_types(b), _f(b, "reward"), b.get("behaviour", "oncePerBlock"),
                            _f(b, "cooldownInMs", 1000.0))
                for b in kids
            )  # fmt: skip
        elif t == "RewardForSendingCommand":
            kw["command_reward"] = _f(h, "reward", -1.0)
        elif t == "RewardForReachingPosition":
            kw["positions"] = tuple(
                PositionReward(_f(m, "x"), _f(m, "y"), _f(m, "z"), _f(m, "tolerance"),
                               _f(m, "reward"), _bool(m, "oneshot", True))
                for m in kids
            )  # fmt: skip
        elif t == "RewardForMissionEnd":
            kw["mission_end"] = tuple((r.get("description", ""), _f(r, "reward")) for r in kids)
            kw["death_reward"] = _f(h, "rewardForDeath")
        elif t == "RewardForTimeTaken":
            kw["time"] = TimeReward(_f(h, "initialReward"), _f(h, "delta"), h.get("density", ""))
        elif t == "RewardForSendingMatchingChatMessage":
            kw["chat"] = tuple((c.get("regex", ""), _f(c, "reward")) for c in kids)
        elif t in ("RewardForCatchingMob", "AgentQuitFromCatchingMob"):
            key = "catch" if t == "RewardForCatchingMob" else "quit_catch"
            kw[key] = tuple(
                CatchRule(_types(m), _bool(m, "global", False), _f(m, "reward"),
                          m.get("description", ""))
                for m in kids
            )  # fmt: skip
        elif t in ("AgentQuitFromCollectingItem", "AgentQuitFromTouchingBlockType"):
            key = "quit_collect" if t == "AgentQuitFromCollectingItem" else "quit_touch"
            kw[key] = tuple(TypedQuit(_types(i), i.get("description", "")) for i in kids)
        elif t == "AgentQuitFromReachingPosition":
            kw["quit_positions"] = tuple(
                PositionQuit(_f(m, "x"), _f(m, "y"), _f(m, "z"), _f(m, "tolerance", 0.5),
                             m.get("description", ""))
                for m in kids
            )  # fmt: skip
        elif t == "RewardForStructureCopying":
            k = {_tag(c): c for c in kids}
            q = k.get("AddQuitProducer")
            kw["copying"] = StructureCopying(
                ((k["RewardDensity"].text or "") if "RewardDensity" in k else "").strip(),
                _f(h, "rewardScale", 5.0), _f(h, "rewardForCompletion", 200.0),
                h.get("rewardDistribution", ""), None if q is None else q.get("description", ""),
            )  # fmt: skip
        elif t == "AgentQuitFromTimeUp":
            kw["quit_time"] = (_f(h, "timeLimitMs"), h.get("description", ""))
        elif t == "AgentQuitFromReachingCommandQuota":
            if h.get("total") is not None:
                kw["quota_total"] = (int(h.get("total", "0")), h.get("description", ""))
            kw["quotas"] = tuple(
                CommandQuota(frozenset(q.get("commands", "").split()),
                             int(q.get("quota", "0")), q.get("description", ""))
                for q in kids
            )  # fmt: skip
    return Rules(**kw)  # type: ignore[arg-type]
