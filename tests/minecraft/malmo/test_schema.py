"""Malmo's mission schema: every mission graft builds passes it, and what Malmo's schema
refuses is refused with a reason naming the element."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from minecraft.agent.travel_task import TravelMission, travel_mission_xml
from minecraft.malmo import schema
from minecraft.malmo.mission import MissionError, parse_mission
from minecraft.malmo.mission_xml import SAMPLE_PATH, mission_xml, obtain_diamond
from minecraft.malmo.protocol import mission_init_xml
from minecraft.malmo.xsd_elements import SchemaError
from tests.minecraft.conftest import flat_mission

SIM_MISSIONS = Path(__file__).parents[1] / "sim" / "missions"


def _graft_missions() -> list[str]:
    travel = TravelMission(3, (0.5, 66.0, 0.5), (4, 66, 0), ((0, 66, 0), (4, 66, 0)))
    return [
        obtain_diamond(),
        obtain_diamond(seed=11),
        *(p.read_text() for p in sorted(SAMPLE_PATH.parent.glob("*.xml"))),
        mission_xml(),
        mission_xml(width=None, height=None, flat="3;7,2*3,2;1;", grid_radius=0, observations=""),
        mission_xml(
            handlers="continuous discrete inventory craft quit absolute",
            placement=(1.5, 70.0, -2.5),
            inventory=((0, "wooden_pickaxe", 1), (5, "planks", 64)),
            decorators='<DrawBlock x="1" y="64" z="0" type="stone"/>',
            rewards='<RewardForSendingCommand reward="-1"/>',
            time_limit_ms=None,
        ),
        flat_mission(video=True, time_limit_ms=500),
        travel_mission_xml(travel, time_limit_ticks=600),
    ]


@pytest.mark.parametrize("index", range(len(_graft_missions())))
def test_every_mission_graft_builds_passes_malmos_schema(index: int) -> None:
    xml = _graft_missions()[index]
    schema.validate(ET.fromstring(xml))
    schema.validate(ET.fromstring(mission_init_xml(xml, "exp")))  # as sent on the wire


@pytest.mark.parametrize("path", sorted(SIM_MISSIONS.glob("*.xml")), ids=lambda p: p.name)
def test_the_malmo_style_test_missions_pass_the_schema(path: Path) -> None:
    schema.validate(ET.parse(path).getroot())


GOOD = (SIM_MISSIONS / "pen_chase.xml").read_text()


@pytest.mark.parametrize(
    ("old", "new", "reason"),
    [
        # A misspelt handler, with the name Malmo knows.
        ("<ObservationFromFullStats/>", "<ObservationFromFullStat/>",
         "<AgentHandlers>: unknown element <ObservationFromFullStat> (did you mean "
         "'ObservationFromFullStats'?)"),
        # Order matters in sequences: decorators come after the world generator...
        ("<FlatWorldGenerator", "<DrawingDecorator><DrawBlock x='0' y='9' z='0' type='stone'/>"
         "</DrawingDecorator><FlatWorldGenerator",
         "<ServerHandlers>: expected <FlatWorldGenerator> or <FileWorldGenerator> or "
         "<DefaultWorldGenerator> or <BiomeGenerator>, found <DrawingDecorator>"),
        # ... and the agent's Name before its AgentStart.
        ("<Name>Herder</Name>", "", "<AgentSection>: expected <Name>, found <AgentStart>"),
        # Missing required elements and attributes.
        ("<About><Summary>Pen chase</Summary></About>", "<About></About>",
         "<About>: expected <Summary>"),
        ('<DrawBlock x="5" y="3" z="5" type="brick_block"/>',
         '<DrawBlock x="5" y="3" type="brick_block"/>', "required attribute 'z' is missing"),
        # Handlers appear at most once.
        ("<ObservationFromFullStats/>", "<ObservationFromFullStats/><ObservationFromFullStats/>",
         "<ObservationFromFullStats> appears twice"),
        # Types: block names, integers where the schema says xs:int, ranges, enumerations.
        ('type="brick_block"/>', 'type="brick_blok"/>',
         "'brick_blok' is not a Minecraft block type (did you mean 'brick_block'?)"),
        ('<DrawBlock x="5"', '<DrawBlock x="5.5"', "x='5.5' is not an integer"),
        ("<StartTime>3000</StartTime>", "<StartTime>24000</StartTime>", "is outside [0, 23999]"),
        ('behaviour="onceOnly"', 'behaviour="twice"', "'twice' is not a touch behaviour"),
        ('<AgentSection mode="Survival">', '<AgentSection mode="Hardcore">',
         "'Hardcore' is not a game mode"),
        ('<Grid name="pen" ', '<Grid name="pen" relative="true" ',
         "attribute 'relative' is not allowed"),
        ("<DiscreteMovementCommands/>",
         "<DiscreteMovementCommands><ModifierList><command>fly</command></ModifierList>"
         "</DiscreteMovementCommands>", "'fly' is not a DiscreteMovementCommands verb"),
        ('<DrawEntity x="3.5" y="4" z="4.5" type="Pig"/>',
         '<DrawEntity x="3.5" y="4" z="4.5" type="Unicorn"/>', "is not a spawnable entity type"),
        ("<Width>32</Width>", "<Width>wide</Width>", "'wide' is not an integer"),
        ("<MsPerTick>20</MsPerTick>", "<MsPerTick>0</MsPerTick>", "is outside [1, inf]"),
    ],
)  # fmt: skip
def test_what_malmos_schema_refuses_is_refused_by_name(old: str, new: str, reason: str) -> None:
    assert old in GOOD
    bad = GOOD.replace(old, new, 1)
    with pytest.raises(SchemaError) as e:
        schema.validate(ET.fromstring(bad))
    assert reason in str(e.value)
    with pytest.raises(MissionError, match="not a valid Malmo mission"):
        parse_mission(bad)


def test_platform_version_must_be_malmos() -> None:
    wire = mission_init_xml(GOOD, "exp")
    schema.validate(ET.fromstring(wire))
    old = wire.replace('PlatformVersion="0.37.0"', 'PlatformVersion="0.36.0"')
    with pytest.raises(SchemaError, match="version mismatch: got 0.36.0, expected 0.37.0"):
        schema.validate(ET.fromstring(old))


def test_elements_must_be_in_malmos_namespace() -> None:
    bare = GOOD.replace(' xmlns="http://ProjectMalmo.microsoft.com"', "")
    with pytest.raises(SchemaError, match="not in Malmo's namespace"):
        schema.validate(ET.fromstring(bare))


def test_parse_reads_the_agent_section_of_the_client_role() -> None:
    two = (SIM_MISSIONS / "builders.xml").read_text()
    assert parse_mission(mission_init_xml(two, "exp", role=1)).agent_name == "Bob"
    assert parse_mission(two).agent_name == "Ann"
    with pytest.raises(MissionError, match="ClientRole 2 has no AgentSection"):
        parse_mission(two, role=2)
