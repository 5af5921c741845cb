"""Every mission graft builds carries what real Malmo needs: a VideoProducer (Malmo never
queues the commands of a mission without one), small when the agent reads no pixels."""

from __future__ import annotations

import random

import pytest

from minecraft.agent.travel_task import draw_missions, travel_mission_xml
from minecraft.malmo.client import with_seed
from minecraft.malmo.mission import parse_mission
from minecraft.malmo.mission_xml import SAMPLE_PATH, SMALL_VIDEO, mission_xml, obtain_diamond
from minecraft.sim import worldgen
from tests.minecraft.conftest import flat_mission


def _missions() -> dict[str, str]:
    travel = draw_missions(3, 1, random.Random(0), terrain=worldgen.generate(3))[0]
    return {
        "mission_xml()": mission_xml(),
        "mission_xml(width=None)": mission_xml(width=None, height=None),
        "obtain_diamond()": obtain_diamond(),
        "obtain_diamond(pixels=False)": obtain_diamond(pixels=False),
        "obtain_diamond.xml": SAMPLE_PATH.read_text(),
        "travel_mission_xml": travel_mission_xml(travel, time_limit_ticks=100),
        "flat_mission()": flat_mission(),
    }


@pytest.mark.parametrize("name", list(_missions()))
def test_every_built_mission_has_a_video_producer(name: str) -> None:
    m = parse_mission(_missions()[name])
    assert m.has_video and m.width > 0 and m.height > 0


def test_an_agent_without_pixels_gets_the_small_frame() -> None:
    for xml in (mission_xml(width=None, height=None), obtain_diamond(pixels=False)):
        m = parse_mission(xml)
        assert (m.width, m.height) == SMALL_VIDEO
    assert (parse_mission(obtain_diamond()).width, parse_mission(obtain_diamond()).height) == (
        64,
        64,
    )


def test_a_malmo_seed_goes_into_the_default_world_generator() -> None:
    xml = with_seed(mission_xml(seed=5), 42)
    assert parse_mission(xml).seed == 42 and xml.count("seed=") == 1
    assert parse_mission(with_seed(mission_xml(), 7)).seed == 7
    flat = mission_xml(flat="3;7,2*3,2;1;")
    assert with_seed(flat, 7) == flat  # Malmo reads no seed for a flat world
