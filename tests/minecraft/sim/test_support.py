"""What the simulator implements, refuses and approximates: every element Malmo's schema
defines is accounted for, every Minecraft block has a simulated stand-in, and refusals
and warnings name what they are about."""

from __future__ import annotations

import pytest

from minecraft import approximate_blocks, names
from minecraft import blocks as B
from minecraft.malmo.agent_section import AGENT_HANDLERS
from minecraft.malmo.mission import MissionError, parse_mission
from minecraft.malmo.server_section import DRAW_OPS, SERVER_HANDLERS
from minecraft.sim import support
from minecraft.sim.world import World
from tests.minecraft.conftest import flat_mission


def test_every_schema_element_is_implemented_or_refused_by_name() -> None:
    defined = (
        set(AGENT_HANDLERS) | set(SERVER_HANDLERS) | set(DRAW_OPS)
        | {"EnderBoxInventory"}
    )  # fmt: skip
    assert not support.IMPLEMENTED & support.REFUSED.keys()
    assert defined == support.IMPLEMENTED | support.REFUSED.keys()


def test_every_minecraft_block_is_simulated_or_refused_by_name() -> None:
    simulated = set(B.NAMES)
    assert set(names.BLOCK_TYPES) == simulated | approximate_blocks.REFUSED.keys()
    assert all(B.BLOCKS[B.ID[n]].mc_id == names.numeric_id(n) for n in simulated)
    assert len(B.BLOCKS) <= 256  # ids are uint8


def _check(**kw: object) -> list[str]:
    return support.check(parse_mission(flat_mission(**kw)))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("kw", "reason"),
    [
        ({"decorators": '<DrawEntity x="1" y="4" z="1" type="Zombie"/>'},
         '<DrawEntity type="Zombie"> is refused: the simulator has only Chicken, Cow, Pig'),
        ({"decorators": '<DrawBlock x="1" y="4" z="1" type="fire"/>'},
         "block 'fire' is refused: fire spread and burning are not simulated"),
        ({"decorators": '<DrawSign x="1" y="4" z="1" type="standing_sign"/>'},
         "<DrawSign> is refused: signs are not simulated"),
        ({"rewards": '<RewardForPossessingItem><Item type="log" reward="1"/>'
                     "</RewardForPossessingItem>"},
         "<RewardForPossessingItem> is refused"),
        ({"rewards": "<DepthProducer><Width>4</Width><Height>4</Height></DepthProducer>"},
         "<DepthProducer> is refused: only VideoProducer frames"),
        ({"decorators": '<DrawBlock x="900" y="4" z="1" type="stone"/>'},
         "the simulator's worlds are at most 448 wide"),
    ],
)  # fmt: skip
def test_refusals_name_the_element(kw: dict, reason: str) -> None:
    with pytest.raises(MissionError) as e:
        _check(**kw)
    assert reason in str(e.value)


def test_game_modes_and_viewpoints_other_than_malmos_default_are_refused() -> None:
    adventure = flat_mission().replace('mode="Survival"', 'mode="Adventure"')
    with pytest.raises(MissionError, match='<AgentSection mode="Adventure"> is refused'):
        support.check(parse_mission(adventure))
    creative = flat_mission().replace('mode="Survival"', 'mode="Creative"')
    (warning,) = support.check(parse_mission(creative))
    assert warning.startswith("mode Creative: no damage") and "flying is not simulated" in warning
    third = flat_mission(video=True).replace('want_depth="false"', 'viewpoint="1"')
    with pytest.raises(MissionError, match='viewpoint="1"> is refused'):
        support.check(parse_mission(third))


def test_approximations_are_reported_and_the_blocks_keep_their_names() -> None:
    deco = (
        '<DrawBlock x="1" y="4" z="1" type="spruce_fence"/>'
        '<DrawBlock x="2" y="4" z="1" type="red_flower"/>'
        '<DrawBlock x="3" y="4" z="1" type="wool" colour="RED"/>'
    )
    warnings = _check(decorators=deco)
    assert "spruce_fence: drawn as a full solid cube (its real shape is not simulated)" in warnings
    assert "red_flower: passable, no collision (not climbable)" in warnings
    assert "colour and variant attributes are not simulated (blocks keep one look)" in warnings
    world = World(parse_mission(flat_mission(decorators=deco)), seed=0)
    fence, flower = world.get(1, 4, 1), world.get(2, 4, 1)
    assert (B.NAMES[fence], bool(B.SOLID[fence])) == ("spruce_fence", True)
    assert (B.NAMES[flower], bool(B.SOLID[flower])) == ("red_flower", False)
    assert _check() == []
