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

The element rules are ``xsd_elements``; the sections' handlers are ``agent_section`` and
``server_section``; this module puts them together as a ``<Mission>`` and a
``<MissionInit>``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from minecraft.malmo.agent_section import AGENT_HANDLERS, AGENT_START
from minecraft.malmo.server_section import DECORATORS, GENERATORS, SERVER_QUITS
from minecraft.malmo.xsd_elements import (
    SchemaError,
    all_of,
    check,
    el,
    local_name,
    many,
    one,
    opt,
    seq,
    text,
)
from minecraft.malmo.xsd_types import BOOL, INT, MOB_LIST, STRING, int_range, one_of

PLATFORM_VERSION = "0.37.0"  # the Malmo mod version MalmoEnv 0.37.0 runs

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
    name = local_name(root, "")
    if name == "MissionInit":
        check(root, MISSION_INIT, "<MissionInit>")
        got = root.get("PlatformVersion")
        if got != PLATFORM_VERSION:
            raise SchemaError(
                f"<MissionInit PlatformVersion={got!r}>: Malmo {PLATFORM_VERSION} refuses it "
                f"(version mismatch: got {got}, expected {PLATFORM_VERSION})"
            )
    elif name == "Mission":
        check(root, MISSION, "<Mission>")
    else:
        raise SchemaError(f"the root element is <{name}>, not <Mission> or <MissionInit>")
