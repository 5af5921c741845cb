"""Which part of a multi-agent mission is whose: Malmo gives role k the k-th
AgentSection, joins roles > 0 to role 0's server through ``MinecraftServerConnection``
and wraps turn-based command handlers in ``TurnBasedCommands``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from typing import Optional

from minecraft.malmo.mission import MissionError


def _tag(e: ET.Element) -> str:
    return e.tag.rsplit("}", 1)[-1]


@dataclass(frozen=True)
class RoleMission:
    """One role's view of a mission.

    Attributes:
        xml: the mission with only this role's AgentSection, TurnBasedCommands unwrapped.
        agent_count: AgentSections in the full mission.
        turn_position: TurnBasedCommands ``requestedPosition``, or None (not turn-based).
        turn_handlers: command handler kinds inside TurnBasedCommands ("DiscreteMovement").
        server_port: MinecraftServerConnection port of the MissionInit (0 if absent).
    """

    xml: str
    agent_count: int
    turn_position: Optional[int]
    turn_handlers: frozenset[str]
    server_port: int


def role_mission(xml: str, role: int) -> RoleMission:
    """Cut ``role``'s part out of a mission (or the MissionInit wrapping it).

    Raises:
        MissionError: the XML does not parse or has no AgentSection ``role``.
    """
    try:
        root = ET.fromstring(xml)
    except ET.ParseError as e:
        raise MissionError(f"mission XML does not parse: {e}") from None
    port = 0
    for child in root:
        if _tag(child) == "MinecraftServerConnection":
            raw = child.get("port", "0")
            try:
                port = int(raw)
            except ValueError:
                raise MissionError(f"MinecraftServerConnection port {raw!r}") from None
    mission = root if _tag(root) == "Mission" else next(
        (e for e in root if _tag(e) == "Mission"), None
    )  # fmt: skip
    if mission is None:
        raise MissionError("no <Mission> element")
    sections = [e for e in mission if _tag(e) == "AgentSection"]
    if not 0 <= role < len(sections):
        raise MissionError(f"role {role} but the mission has {len(sections)} AgentSection(s)")
    for i, s in enumerate(sections):
        if i != role:
            mission.remove(s)
    position: Optional[int] = None
    kinds: set[str] = set()
    for handlers in (e for e in sections[role] if _tag(e) == "AgentHandlers"):
        for tb in [e for e in handlers if _tag(e) == "TurnBasedCommands"]:
            try:
                position = int(tb.get("requestedPosition", "0"))
            except ValueError:
                raise MissionError(
                    f"TurnBasedCommands requestedPosition={tb.get('requestedPosition')!r}"
                ) from None
            at = list(handlers).index(tb)
            handlers.remove(tb)
            for j, child in enumerate(tb):
                kinds.add(_tag(child).removesuffix("Commands"))
                handlers.insert(at + j, child)
    return RoleMission(
        ET.tostring(mission, encoding="unicode"), len(sections), position,
        frozenset(kinds), port,
    )  # fmt: skip
