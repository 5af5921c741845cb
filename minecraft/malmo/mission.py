"""Parse a Malmo mission XML (or the ``<MissionInit>`` that wraps it) into a ``Mission``.

The XML is first checked against Malmo's schema (``schema.validate``): a mission real
Malmo would refuse is refused here too, with the element at fault named. Then the
handlers are read into plain dataclasses. Every element present is recorded in
``Mission.elements``, so a consumer (the simulator) can refuse, by name, the ones it
does not implement instead of ignoring them.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
import zlib
from dataclasses import dataclass, field
from typing import Optional

from minecraft.malmo import decorator_specs as D
from minecraft.malmo import schema
from minecraft.malmo.agent_section import COMMAND_VERBS
from minecraft.malmo.mission_rules import Rules, finite_attr, parse_rules
from minecraft.malmo.xsd_elements import SchemaError

# Handler element -> the verbs it implements (lower case, as Malmo compares them).
HANDLER_VERBS: dict[str, frozenset[str]] = {
    k: frozenset(v.lower() for v in verbs) for k, verbs in COMMAND_VERBS.items()
}


class MissionError(ValueError):
    """The mission XML cannot be used; the message names the element at fault."""


@dataclass(frozen=True)
class Grid:
    """An ObservationFromGrid grid: its name and inclusive bounds, relative to the
    player's block unless ``absolute`` (``absoluteCoords="true"``: world coordinates)."""

    name: str
    lo: tuple[int, int, int]
    hi: tuple[int, int, int]
    absolute: bool = False


@dataclass(frozen=True)
class EntityRange:
    """An ObservationFromNearbyEntities range (half-widths in blocks, exclusive) that
    is reported every ``every`` ticks (``update_frequency``)."""

    name: str
    x: float
    y: float
    z: float
    every: int = 1


@dataclass(frozen=True)
class Handler:
    """A command handler: its element (``"ContinuousMovementCommands"``...), the verbs
    it implements and its ModifierList, applied as Malmo applies it.

    Attributes:
        kind: the element name without ``Commands`` (``"ContinuousMovement"``).
        verbs: lower-case verbs the handler implements.
        allow: an allow-list's entries as written, or None.
        deny: a deny-list's entries as written, or None.
        turn_speed: ContinuousMovementCommands ``turnSpeedDegs``.
        description: MissionQuitCommands ``quitDescription`` (the quit code).
    """

    kind: str
    verbs: frozenset[str]
    allow: Optional[frozenset[str]] = None
    deny: Optional[frozenset[str]] = None
    turn_speed: float = 180.0
    description: str = ""

    def accepts(self, verb: str) -> bool:
        """Whether this handler takes ``verb`` (already lower-cased).

        Malmo lower-cases the verb and then looks it up in the lists as written, so a
        list entry with capitals (``setYaw``) never matches; an empty allow-list
        allows nothing.
        """
        if verb not in self.verbs:
            return False
        if self.deny is not None and verb in self.deny:
            return False
        return self.allow is None or verb in self.allow


@dataclass(frozen=True)
class DrawOp:
    """A DrawingDecorator operation: ``kind`` is block, cuboid, sphere, line, item or
    entity; ``coords`` as the element gives them (x y z, corners, or x y z radius)."""

    kind: str
    coords: tuple[float, ...]
    type: str


@dataclass(frozen=True)
class Subgoal:
    """An ObservationFromSubgoalPositionList ``Point``: passed once the agent is within
    ``tolerance`` of it (x and z distances added)."""

    x: float
    y: float
    z: float
    tolerance: float = 0.5
    description: str = ""


@dataclass(frozen=True)
class Mission:
    """What a Malmo mission asks for, for one agent (``role``).

    Attributes:
        agent_name: the agent's Name.
        agent_count: number of AgentSections.
        role: which AgentSection this is (the MissionInit's ClientRole).
        mode: the AgentSection's game mode (Survival, Creative, Adventure, Spectator).
        elements: every element name in the mission (for refusing unsupported ones).
        has_video: a VideoProducer is present (otherwise frames are empty).
        width: frame width in pixels.
        height: frame height in pixels.
        want_depth: the frame has a 4th (depth) channel.
        viewpoint: VideoProducer viewpoint (0 first person, 1 and 2 third person).
        ms_per_tick: ModSettings/MsPerTick, or None to use the server's default.
        time_limit_ms: ServerQuitFromTimeUp limit in game milliseconds (50 per tick).
        server_quit_description: ServerQuitFromTimeUp ``description`` (the quit code).
        start_time: ServerInitialConditions/Time/StartTime (time of day in ticks).
        passage_of_time: AllowPassageOfTime.
        weather: ServerInitialConditions/Weather.
        allow_spawning: ServerInitialConditions/AllowSpawning.
        flat_generator: FlatWorldGenerator generatorString, or None.
        seed: DefaultWorldGenerator seed, or None (the server chooses).
        diamond_keep: the fraction of diamond veins the default generator keeps, from
            its ``generatorOptions`` JSON (``{"diamondKeep": 0.25}``, a key of the
            simulator's own), or None (the server's setting).
        drawing: DrawingDecorator operations, in order.
        maze: the MazeDecorator, or None.
        classroom: the ClassroomDecorator, or None.
        build_battle: the BuildBattleDecorator, or None.
        placement: AgentStart/Placement (x, y, z, yaw, pitch) or None (world spawn).
        start_inventory: (slot, item, quantity) from AgentStart/Inventory.
        full_stats: ObservationFromFullStats.
        grids: ObservationFromGrid grids.
        full_inventory: ObservationFromFullInventory.
        inventory_flat: its ``flat`` attribute (Malmo's default is true).
        hotbar: ObservationFromHotBar.
        nearby: ObservationFromNearbyEntities ranges.
        ray: ObservationFromRay.
        distances: ObservationFromDistance markers (name, x, y, z).
        recent_commands: ObservationFromRecentCommands.
        chat: ObservationFromChat.
        subgoals: ObservationFromSubgoalPositionList points, in order.
        handlers: command handlers in XML order (the first that takes a command runs it).
        rules: rewards and agent quits.
        colour_or_variant: some block or item names a colour or variant.
    """

    agent_name: str = "agent"
    agent_count: int = 1
    role: int = 0
    mode: str = "Survival"
    elements: frozenset[str] = frozenset()
    has_video: bool = False
    width: int = 0
    height: int = 0
    want_depth: bool = False
    viewpoint: int = 0
    ms_per_tick: Optional[int] = None
    time_limit_ms: Optional[float] = None
    server_quit_description: str = ""
    start_time: int = 6000
    passage_of_time: bool = True
    weather: str = "normal"
    allow_spawning: bool = False
    flat_generator: Optional[str] = None
    seed: Optional[int] = None
    diamond_keep: Optional[float] = None
    drawing: tuple[DrawOp, ...] = ()
    maze: Optional[D.MazeSpec] = None
    classroom: Optional[D.ClassroomSpec] = None
    build_battle: Optional[D.BuildBattleSpec] = None
    placement: Optional[tuple[float, float, float, float, float]] = None
    start_inventory: tuple[tuple[int, str, int], ...] = ()
    full_stats: bool = False
    grids: tuple[Grid, ...] = ()
    full_inventory: bool = False
    inventory_flat: bool = True
    hotbar: bool = False
    nearby: tuple[EntityRange, ...] = ()
    ray: bool = False
    distances: tuple[tuple[str, float, float, float], ...] = ()
    recent_commands: bool = False
    chat: bool = False
    subgoals: tuple[Subgoal, ...] = ()
    handlers: tuple[Handler, ...] = ()
    rules: Rules = field(default_factory=Rules)
    colour_or_variant: bool = False

    def handler_for(self, verb: str) -> Optional[Handler]:
        """The first handler implementing ``verb`` (any case), or None: which handler a
        command belongs to, before its allow and deny lists are applied."""
        verb = verb.lower()
        return next((h for h in self.handlers if verb in h.verbs), None)

    @property
    def channels(self) -> int:
        """Bytes per pixel of the frame (3, or 4 with depth)."""
        return 4 if self.want_depth else 3

    def block_types(self) -> frozenset[str]:
        """Every block type the mission draws."""
        return frozenset(op.type for op in self.drawing if op.kind not in ("item", "entity"))


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


def _num(e: ET.Element, attr: str, default: Optional[float] = None) -> float:
    try:
        v = finite_attr(e, attr)
    except ValueError as error:
        raise MissionError(str(error)) from None
    if v is None:
        if default is None:
            raise MissionError(f"<{_tag(e)}> needs attribute {attr!r}")
        return default
    return v


def _text(e: Optional[ET.Element], name: str) -> Optional[str]:
    c = _child(e, name)
    return None if c is None or c.text is None else c.text.strip()


def _bool(raw: Optional[str], default: bool) -> bool:
    return default if raw is None else raw.strip() in ("true", "1")


def seed_from_text(text: str) -> int:
    """Minecraft-style seed: integers are used as is, other strings are hashed."""
    text = text.strip()
    try:
        return int(text)
    except ValueError:
        return zlib.crc32(text.encode())


def parse_mission(xml: str | bytes, role: Optional[int] = None) -> Mission:
    """Check and parse mission XML (a ``<Mission>`` or a ``<MissionInit>`` wrapping one).

    Args:
        xml: the XML text.
        role: which AgentSection to read; None reads the MissionInit's ClientRole
            (0 for a bare ``<Mission>``).

    Raises:
        MissionError: malformed XML, a schema violation (Malmo would refuse it too) or
            values that cannot be used; the message names the element.
    """
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise MissionError(f"mission XML does not parse: {e}") from None
    try:
        schema.validate(root)
    except SchemaError as e:
        raise MissionError(f"not a valid Malmo mission: {e}") from None
    mission = root if _tag(root) == "Mission" else _child(root, "Mission")
    assert mission is not None  # the schema requires it
    if role is None:
        role = int(_text(root, "ClientRole") or 0) if _tag(root) == "MissionInit" else 0
    agents = _children(mission, "AgentSection")
    if not 0 <= role < len(agents):
        raise MissionError(f"ClientRole {role} has no AgentSection ({len(agents)} agents)")
    agent = agents[role]
    kw: dict[str, object] = {
        "agent_count": len(agents),
        "role": role,
        "agent_name": (_text(agent, "Name") or "agent"),
        "mode": agent.get("mode", "Survival"),
        "elements": frozenset(_tag(e) for e in mission.iter()),
        "colour_or_variant": any(
            e.get("colour") is not None or e.get("variant") is not None for e in mission.iter()
        ),
    }
    ms = _text(_child(mission, "ModSettings"), "MsPerTick")
    if ms is not None:
        kw["ms_per_tick"] = int(ms)
    server = _child(mission, "ServerSection")
    _initial_conditions(_child(server, "ServerInitialConditions"), kw)
    _server_handlers(_child(server, "ServerHandlers"), kw)
    start = _child(agent, "AgentStart")
    pl = _child(start, "Placement")
    if pl is not None:
        kw["placement"] = tuple(
            _num(pl, a, d) for a, d in (("x", None), ("y", None), ("z", None), ("yaw", 0.0),
                                       ("pitch", 0.0))
        )  # fmt: skip
    inv = _child(start, "Inventory")
    kw["start_inventory"] = tuple(
        (int(_num(i, "slot")), i.get("type", "air").strip(), int(_num(i, "quantity", 1.0)))
        for i in (list(inv) if inv is not None else [])
    )
    _agent_handlers(_child(agent, "AgentHandlers"), kw)
    return Mission(**kw)  # type: ignore[arg-type]


def _diamond_keep(options: str) -> Optional[float]:
    """``diamondKeep`` from a DefaultWorldGenerator's generatorOptions JSON (Minecraft's
    customised-world keys are accepted and not modelled), or None."""
    if not options.strip():
        return None
    try:
        parsed = json.loads(options)
    except ValueError:
        raise MissionError(
            f"DefaultWorldGenerator generatorOptions is not JSON: {options!r}"
        ) from None
    if not isinstance(parsed, dict):
        raise MissionError(f"DefaultWorldGenerator generatorOptions is not an object: {options!r}")
    keep = parsed.get("diamondKeep")
    if keep is None:
        return None
    if isinstance(keep, bool) or not isinstance(keep, (int, float)) or not 0 <= keep <= 1:
        raise MissionError(
            f"generatorOptions diamondKeep must be a number within [0, 1], got {keep!r}"
        )
    return float(keep)


def _initial_conditions(init: Optional[ET.Element], kw: dict[str, object]) -> None:
    time_e = _child(init, "Time")
    start = _text(time_e, "StartTime")
    if start is not None:
        kw["start_time"] = int(start)
    kw["passage_of_time"] = _bool(_text(time_e, "AllowPassageOfTime"), True)
    kw["weather"] = _text(init, "Weather") or "normal"
    kw["allow_spawning"] = _bool(_text(init, "AllowSpawning"), False)


def _server_handlers(handlers: Optional[ET.Element], kw: dict[str, object]) -> None:
    drawing: list[DrawOp] = []
    for h in handlers if handlers is not None else []:
        t = _tag(h)
        if t == "FlatWorldGenerator":
            kw["flat_generator"] = h.get("generatorString", "3;7,2*3,2;1;village")
            if (h.get("seed") or "").strip():
                kw["seed"] = seed_from_text(h.get("seed", ""))
        elif t == "DefaultWorldGenerator":
            if (h.get("seed") or "").strip():
                kw["seed"] = seed_from_text(h.get("seed", ""))
            keep = _diamond_keep(h.get("generatorOptions") or "")
            if keep is not None:
                kw["diamond_keep"] = keep
        elif t == "ServerQuitFromTimeUp":
            kw["time_limit_ms"] = _num(h, "timeLimitMs")
            kw["server_quit_description"] = h.get("description", "")
        elif t == "DrawingDecorator":
            drawing.extend(_draw_ops(h))
        elif t == "MazeDecorator":
            kw["maze"] = D.maze(h, len(drawing))
        elif t == "ClassroomDecorator":
            kw["classroom"] = D.classroom(h, len(drawing))
        elif t == "BuildBattleDecorator":
            kw["build_battle"] = D.build_battle(h)
    kw["drawing"] = tuple(drawing)


_DRAW_COORDS = {
    "DrawBlock": ("block", ("x", "y", "z")),
    "DrawItem": ("item", ("x", "y", "z")),
    "DrawEntity": ("entity", ("x", "y", "z")),
    "DrawCuboid": ("cuboid", ("x1", "y1", "z1", "x2", "y2", "z2")),
    "DrawLine": ("line", ("x1", "y1", "z1", "x2", "y2", "z2")),
    "DrawSphere": ("sphere", ("x", "y", "z", "radius")),
}


def _draw_ops(deco: ET.Element) -> list[DrawOp]:
    ops = []
    for d in deco:
        spec = _DRAW_COORDS.get(_tag(d))
        if spec is not None:  # DrawContainer and DrawSign: refused by name by consumers
            kind, attrs = spec
            ops.append(DrawOp(kind, tuple(_num(d, a) for a in attrs), d.get("type", "").strip()))
    return ops


def _modifiers(h: ET.Element) -> dict[str, object]:
    out: dict[str, object] = {}
    ml = _child(h, "ModifierList")
    if ml is not None:
        entries = frozenset((c.text or "").strip() for c in _children(ml, "command"))
        out["allow" if ml.get("type") == "allow-list" else "deny"] = entries
    return out


def _agent_handlers(ah: Optional[ET.Element], kw: dict[str, object]) -> None:
    if ah is None:
        return
    handlers: list[Handler] = []
    nodes = list(ah)
    for tb in _children(ah, "TurnBasedCommands"):
        nodes.extend(tb)  # the handlers a TurnBasedCommands wraps
    for h in nodes:
        t = _tag(h)
        if t in HANDLER_VERBS:
            kind = t.removesuffix("Commands")
            handlers.append(
                Handler(kind, HANDLER_VERBS[t], turn_speed=_num(h, "turnSpeedDegs", 180.0),
                        description=h.get("quitDescription", ""),
                        **_modifiers(h))  # type: ignore[arg-type]
            )  # fmt: skip
        elif t == "VideoProducer":
            kw["has_video"] = True
            kw["width"] = int(_text(h, "Width") or 0)
            kw["height"] = int(_text(h, "Height") or 0)
            if kw["width"] <= 0 or kw["height"] <= 0:  # type: ignore[operator]
                raise MissionError("<VideoProducer> needs positive <Width> and <Height>")
            kw["want_depth"] = _bool(h.get("want_depth"), False)
            kw["viewpoint"] = int(h.get("viewpoint", "0"))
        elif t == "ObservationFromFullInventory":
            kw["full_inventory"] = True
            kw["inventory_flat"] = _bool(h.get("flat"), True)
        elif t == "ObservationFromGrid":
            kw["grids"] = tuple(_grid(g) for g in _children(h, "Grid"))
        elif t == "ObservationFromNearbyEntities":
            kw["nearby"] = tuple(
                EntityRange(r.get("name", "entities"), _num(r, "xrange"), _num(r, "yrange"),
                            _num(r, "zrange"), max(1, int(_num(r, "update_frequency", 1))))
                for r in _children(h, "Range")
            )  # fmt: skip
        elif t == "ObservationFromSubgoalPositionList":
            kw["subgoals"] = tuple(
                Subgoal(_num(p, "x"), _num(p, "y"), _num(p, "z"), _num(p, "tolerance", 0.5),
                        p.get("description", ""))
                for p in _children(h, "Point")
            )  # fmt: skip
        elif t == "ObservationFromDistance":
            kw["distances"] = tuple(
                (m.get("name", "").strip(), _num(m, "x"), _num(m, "y"), _num(m, "z"))
                for m in _children(h, "Marker")
            )
        else:
            flag = _FLAGS.get(t)
            if flag is not None:
                kw[flag] = True
    kw["handlers"] = tuple(handlers)
    try:
        kw["rules"] = parse_rules(ah)
    except ValueError as e:
        raise MissionError(str(e)) from None


_FLAGS = {
    "ObservationFromFullStats": "full_stats",
    "ObservationFromRay": "ray",
    "ObservationFromHotBar": "hotbar",
    "ObservationFromRecentCommands": "recent_commands",
    "ObservationFromChat": "chat",
}


def _grid(g: ET.Element) -> Grid:
    lo, hi = _child(g, "min"), _child(g, "max")
    assert lo is not None and hi is not None  # the schema requires both
    lo_t = tuple(int(_num(lo, a)) for a in "xyz")
    hi_t = tuple(int(_num(hi, a)) for a in "xyz")
    name = g.get("name", "grid").strip()
    if any(a > b for a, b in zip(lo_t, hi_t, strict=True)):
        raise MissionError(f"<Grid name={name!r}> has min > max")
    return Grid(name, lo_t, hi_t, _bool(g.get("absoluteCoords"), False))  # type: ignore[arg-type]
