"""Parse a Malmo mission XML (or the ``<MissionInit>`` that wraps it) into a ``Mission``.

Only the parts the simulator models are read; everything else is ignored, as Malmo
ignores handlers it does not need. Element names are matched without their XML
namespace, so both namespaced (``http://ProjectMalmo.microsoft.com``) and bare missions
parse.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass, field
from typing import Optional

DEFAULT_VERBS: dict[str, tuple[str, ...]] = {
    "ContinuousMovement": ("jump", "move", "pitch", "strafe", "turn", "crouch", "attack", "use"),
    "DiscreteMovement": (
        "move",
        "jumpmove",
        "strafe",
        "jumpstrafe",
        "turn",
        "movenorth",
        "moveeast",
        "movesouth",
        "movewest",
        "jumpnorth",
        "jumpeast",
        "jumpsouth",
        "jumpwest",
        "jump",
        "look",
        "attack",
        "use",
        "jumpuse",
    ),  # fmt: skip
    "AbsoluteMovement": ("tpx", "tpy", "tpz", "tp", "setYaw", "setPitch"),
    "Inventory": ("swapInventoryItems", "combineInventoryItems", "discardCurrentItem")
    + tuple(f"hotbar.{i}" for i in range(1, 10)),
    "SimpleCraft": ("craft",),
    "MissionQuit": ("quit",),
    "Chat": ("chat",),
}


class MissionError(ValueError):
    """The mission XML cannot be used; the message names the element at fault."""


@dataclass(frozen=True)
class Grid:
    """An ObservationFromGrid grid: its name and inclusive bounds relative to the player."""

    name: str
    lo: tuple[int, int, int]
    hi: tuple[int, int, int]


@dataclass(frozen=True)
class EntityRange:
    """An ObservationFromNearbyEntities range (half-widths in blocks)."""

    name: str
    x: float
    y: float
    z: float


@dataclass(frozen=True)
class Handler:
    """A command handler: its kind (``"ContinuousMovement"``...) and the verbs it accepts."""

    kind: str
    verbs: frozenset[str]
    turn_speed: float = 180.0


@dataclass(frozen=True)
class TouchReward:
    """RewardForTouchingBlockType entry."""

    types: frozenset[str]
    reward: float
    behaviour: str


@dataclass(frozen=True)
class DrawOp:
    """A DrawingDecorator operation: ``kind`` is block, cuboid, item or entity."""

    kind: str
    coords: tuple[float, ...]
    type: str


@dataclass(frozen=True)
class Mission:
    """What the simulator needs from a mission.

    Attributes:
        agent_name: the agent's Name.
        agent_count: number of AgentSections (only 1 is simulated).
        has_video: a VideoProducer is present (otherwise frames are empty).
        width: frame width in pixels.
        height: frame height in pixels.
        want_depth: the frame has a 4th (depth) channel.
        ms_per_tick: ModSettings/MsPerTick, or None to use the server's default.
        time_limit_ms: ServerQuitFromTimeUp limit in game milliseconds (50 per tick).
        start_time: ServerInitialConditions/Time/StartTime (time of day in ticks).
        passage_of_time: AllowPassageOfTime.
        flat_generator: FlatWorldGenerator generatorString, or None.
        seed: DefaultWorldGenerator seed, or None (the server chooses).
        drawing: DrawingDecorator operations, in order.
        placement: AgentStart/Placement (x, y, z, yaw, pitch) or None (world spawn).
        start_inventory: (slot, item, quantity) from AgentStart/Inventory.
        full_stats: ObservationFromFullStats.
        grids: ObservationFromGrid grids.
        full_inventory: ObservationFromFullInventory.
        inventory_flat: its ``flat`` attribute (Malmo's default is true).
        nearby: ObservationFromNearbyEntities ranges.
        ray: ObservationFromRay.
        handlers: command handlers in XML order (the first that accepts a verb runs it).
        collect_rewards: RewardForCollectingItem item -> reward.
        touch_rewards: RewardForTouchingBlockType entries.
        command_reward: RewardForSendingCommand reward per command, or None.
        quit_collect: AgentQuitFromCollectingItem item types.
        quit_touch: AgentQuitFromTouchingBlockType block types.
        quit_positions: AgentQuitFromReachingPosition markers (x, y, z, tolerance).
    """

    agent_name: str = "agent"
    agent_count: int = 1
    has_video: bool = False
    width: int = 0
    height: int = 0
    want_depth: bool = False
    ms_per_tick: Optional[int] = None
    time_limit_ms: Optional[float] = None
    start_time: int = 6000
    passage_of_time: bool = True
    flat_generator: Optional[str] = None
    seed: Optional[int] = None
    drawing: tuple[DrawOp, ...] = ()
    placement: Optional[tuple[float, float, float, float, float]] = None
    start_inventory: tuple[tuple[int, str, int], ...] = ()
    full_stats: bool = False
    grids: tuple[Grid, ...] = ()
    full_inventory: bool = False
    inventory_flat: bool = True
    nearby: tuple[EntityRange, ...] = ()
    ray: bool = False
    handlers: tuple[Handler, ...] = ()
    collect_rewards: dict[str, float] = field(default_factory=dict)
    touch_rewards: tuple[TouchReward, ...] = ()
    command_reward: Optional[float] = None
    quit_collect: frozenset[str] = frozenset()
    quit_touch: frozenset[str] = frozenset()
    quit_positions: tuple[tuple[float, float, float, float], ...] = ()

    @property
    def channels(self) -> int:
        """Bytes per pixel of the frame (3, or 4 with depth)."""
        return 4 if self.want_depth else 3

    def handler_for(self, verb: str) -> Optional[Handler]:
        """The first handler that accepts ``verb``, or None (the command is ignored)."""
        for h in self.handlers:
            if verb in h.verbs:
                return h
        return None


def _tag(e: ET.Element) -> str:
    return e.tag.rsplit("}", 1)[-1]


def _child(e: Optional[ET.Element], name: str) -> Optional[ET.Element]:
    if e is None:
        return None
    for c in e:
        if _tag(c) == name:
            return c
    return None


def _children(e: Optional[ET.Element], name: str) -> list[ET.Element]:
    return [] if e is None else [c for c in e if _tag(c) == name]


def _find(e: ET.Element, name: str) -> list[ET.Element]:
    return [c for c in e.iter() if _tag(c) == name]


def _num(e: ET.Element, attr: str, default: Optional[float] = None) -> float:
    raw = e.get(attr)
    if raw is None:
        if default is None:
            raise MissionError(f"<{_tag(e)}> needs attribute {attr!r}")
        return default
    try:
        return float(raw)
    except ValueError:
        raise MissionError(f"<{_tag(e)} {attr}={raw!r}> is not a number") from None


def _text_int(e: Optional[ET.Element], name: str) -> Optional[int]:
    c = _child(e, name)
    if c is None or c.text is None:
        return None
    try:
        return int(float(c.text.strip()))
    except ValueError:
        raise MissionError(f"<{name}>{c.text}</{name}> is not a number") from None


def seed_from_text(text: str) -> int:
    """Minecraft-style seed: integers are used as is, other strings are hashed."""
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        return zlib.crc32(text.encode())


def _handler(e: ET.Element, kind: str) -> Handler:
    allow: set[str] = set()
    deny: set[str] = set()
    for ml in _children(e, "ModifierList"):
        verbs = {(c.text or "").strip() for c in _children(ml, "command")}
        (deny if ml.get("type") == "deny-list" else allow).update(verbs)
    verbs = (allow or set(DEFAULT_VERBS[kind])) - deny
    return Handler(kind, frozenset(verbs), _num(e, "turnSpeedDegs", 180.0))


_HANDLERS = {k + "Commands": k for k in DEFAULT_VERBS}


def parse_mission(xml: str | bytes) -> Mission:
    """Parse mission XML (a ``<Mission>`` or a ``<MissionInit>`` wrapping one).

    Raises:
        MissionError: malformed XML or values the simulator cannot use.
    """
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise MissionError(f"mission XML does not parse: {e}") from None
    mission = root if _tag(root) == "Mission" else _child(root, "Mission")
    if mission is None:
        raise MissionError("no <Mission> element")
    agents = _children(mission, "AgentSection")
    if not agents:
        raise MissionError("<Mission> has no <AgentSection>")
    agent = agents[0]
    server = _child(mission, "ServerSection")
    kw: dict[str, object] = {"agent_count": len(agents)}
    name = _child(agent, "Name")
    if name is not None and name.text:
        kw["agent_name"] = name.text.strip()
    mod = _child(mission, "ModSettings")
    ms = _text_int(mod, "MsPerTick")
    if ms is not None:
        if ms <= 0:
            raise MissionError(f"<MsPerTick>{ms}</MsPerTick> must be positive")
        kw["ms_per_tick"] = ms
    init = _child(server, "ServerInitialConditions")
    time_e = _child(init, "Time")
    start = _text_int(time_e, "StartTime")
    if start is not None:
        kw["start_time"] = start
    pot = _child(time_e, "AllowPassageOfTime")
    if pot is not None and (pot.text or "").strip().lower() == "false":
        kw["passage_of_time"] = False
    handlers = _child(server, "ServerHandlers")
    drawing: list[DrawOp] = []
    for h in handlers if handlers is not None else []:
        t = _tag(h)
        if t == "FlatWorldGenerator":
            kw["flat_generator"] = h.get("generatorString") or "3;7,2*3,2;1;"
        elif t == "DefaultWorldGenerator" and (h.get("seed") or "").strip():
            kw["seed"] = seed_from_text(h.get("seed", ""))
        elif t == "ServerQuitFromTimeUp":
            kw["time_limit_ms"] = _num(h, "timeLimitMs")
        elif t == "DrawingDecorator":
            drawing.extend(_draw_ops(h))
    kw["drawing"] = tuple(drawing)
    start_e = _child(agent, "AgentStart")
    pl = _child(start_e, "Placement")
    if pl is not None:
        kw["placement"] = tuple(
            _num(pl, a, d) for a, d in (("x", None), ("y", None), ("z", None), ("yaw", 0.0),
                                       ("pitch", 0.0))
        )  # fmt: skip
    inv = _child(start_e, "Inventory")
    kw["start_inventory"] = tuple(
        (int(_num(i, "slot")), i.get("type", "air"), int(_num(i, "quantity", 1.0)))
        for i in _children(inv, "InventoryItem")
    )
    _agent_handlers(_child(agent, "AgentHandlers"), kw)
    return Mission(**kw)  # type: ignore[arg-type]


def _draw_ops(deco: ET.Element) -> list[DrawOp]:
    ops = []
    for d in deco:
        t = _tag(d)
        if t == "DrawBlock":
            ops.append(DrawOp("block", tuple(_num(d, a) for a in "xyz"), d.get("type", "air")))
        elif t == "DrawCuboid":
            c = tuple(_num(d, a) for a in ("x1", "y1", "z1", "x2", "y2", "z2"))
            ops.append(DrawOp("cuboid", c, d.get("type", "air")))
        elif t == "DrawItem":
            ops.append(DrawOp("item", tuple(_num(d, a) for a in "xyz"), d.get("type", "air")))
        elif t == "DrawEntity":
            ops.append(DrawOp("entity", tuple(_num(d, a) for a in "xyz"), d.get("type", "Pig")))
    return ops


def _agent_handlers(ah: Optional[ET.Element], kw: dict[str, object]) -> None:
    if ah is None:
        return
    handlers: list[Handler] = []
    nodes = list(ah)
    for tb in _children(ah, "TurnBasedCommands"):
        nodes.extend(tb)  # turn-based wrappers are accepted; commands run in real time
    for h in nodes:
        t = _tag(h)
        if t in _HANDLERS:
            handlers.append(_handler(h, _HANDLERS[t]))
        elif t == "VideoProducer":
            kw["has_video"] = True
            kw["width"] = _text_int(h, "Width") or 0
            kw["height"] = _text_int(h, "Height") or 0
            if kw["width"] <= 0 or kw["height"] <= 0:  # type: ignore[operator]
                raise MissionError("<VideoProducer> needs positive <Width> and <Height>")
            kw["want_depth"] = h.get("want_depth", "false").lower() in ("true", "1")
        elif t == "ObservationFromFullStats":
            kw["full_stats"] = True
        elif t == "ObservationFromRay":
            kw["ray"] = True
        elif t == "ObservationFromFullInventory":
            kw["full_inventory"] = True
            kw["inventory_flat"] = h.get("flat", "true").lower() != "false"
        elif t == "ObservationFromGrid":
            grids = []
            for g in _children(h, "Grid"):
                lo, hi = _child(g, "min"), _child(g, "max")
                if lo is None or hi is None:
                    raise MissionError(f"<Grid name={g.get('name')!r}> needs <min> and <max>")
                lo_t = tuple(int(_num(lo, a)) for a in "xyz")
                hi_t = tuple(int(_num(hi, a)) for a in "xyz")
                if any(a > b for a, b in zip(lo_t, hi_t, strict=True)):
                    raise MissionError(f"<Grid name={g.get('name')!r}> has min > max")
                grids.append(Grid(g.get("name", "grid"), lo_t, hi_t))  # type: ignore[arg-type]
            kw["grids"] = tuple(grids)
        elif t == "ObservationFromNearbyEntities":
            kw["nearby"] = tuple(
                EntityRange(r.get("name", "entities"), _num(r, "xrange"), _num(r, "yrange"),
                            _num(r, "zrange"))
                for r in _children(h, "Range")
            )  # fmt: skip
        elif t == "RewardForCollectingItem":
            kw["collect_rewards"] = {
                ty: _num(i, "reward") for i in _children(h, "Item") for ty in _types(i)
            }
        elif t == "RewardForTouchingBlockType":
            kw["touch_rewards"] = tuple(
                TouchReward(frozenset(_types(b)), _num(b, "reward"),
                            b.get("behaviour", "oncePerBlock"))
                for b in _children(h, "Block")
            )  # fmt: skip
        elif t == "RewardForSendingCommand":
            kw["command_reward"] = _num(h, "reward")
        elif t == "AgentQuitFromCollectingItem":
            kw["quit_collect"] = frozenset(ty for i in _children(h, "Item") for ty in _types(i))
        elif t == "AgentQuitFromTouchingBlockType":
            kw["quit_touch"] = frozenset(ty for b in _children(h, "Block") for ty in _types(b))
        elif t == "AgentQuitFromReachingPosition":
            kw["quit_positions"] = tuple(
                (_num(m, "x"), _num(m, "y"), _num(m, "z"), _num(m, "tolerance", 1.0))
                for m in _children(h, "Marker")
            )
    kw["handlers"] = tuple(handlers)


def _types(e: ET.Element) -> list[str]:
    return [t.removeprefix("minecraft:") for t in e.get("type", "").split()]
