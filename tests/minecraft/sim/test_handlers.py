"""Malmo's handlers as the simulator runs them, driven through the protocol: commands
(case, parameters, lists), rewards, quits and observation producers, each checked
against what Malmo's implementation of it does."""

from __future__ import annotations

import re
import uuid

import pytest

from minecraft.malmo.client import MalmoClient
from minecraft.sim.physics import WALK_SPEED
from minecraft.sim.server import WorldServer
from tests.minecraft.conftest import GROUND, flat_mission


@pytest.fixture
def raw_client(server: WorldServer):
    """Factory: a synchronous client reset into ``flat_mission(**kw)`` after ``edit``."""
    made: list[MalmoClient] = []

    def make(edit=lambda xml: xml, **kw: object) -> MalmoClient:
        c = MalmoClient("127.0.0.1", server.port, synchronous=True, timeout=10)
        c.init(edit(flat_mission(**kw)))  # type: ignore[arg-type]
        c.reset()
        made.append(c)
        return c

    yield make
    for c in made:
        c.close()


def _total(c: MalmoClient, commands: list[str]) -> tuple[float, object]:
    total, r = 0.0, None
    for cmd in commands:
        r = c.step(cmd)
        total += r.reward
    return total, r


# ------------------------------------------------------------------ commands
def test_verbs_are_lower_cased_as_malmo_does(server: WorldServer, sync_client) -> None:
    c = sync_client()
    for _ in range(10):
        r = c.step("MOVE 1\nTurn 0")
    assert r.info["ZPos"] > 1.0
    assert server.status()["ignored_commands"] == 0


def test_allow_lists_compare_the_lower_cased_verb_as_written(server, raw_client) -> None:
    # Malmo lower-cases the verb, then looks it up in the list as written: an allow-list
    # entry "setYaw" never matches, "tpx" does.
    allow = (
        '<AbsoluteMovementCommands><ModifierList type="allow-list"><command>setYaw</command>'
        "<command>tpx</command></ModifierList></AbsoluteMovementCommands>"
    )
    c = raw_client(lambda x: x.replace("<AbsoluteMovementCommands/>", allow))
    r = c.step("setYaw 90\ntpx 3.5")
    r = c.step("")
    assert r.info["Yaw"] == 0.0 and r.info["XPos"] == 3.5
    assert server.status()["ignored_commands"] == 1


def test_jump_and_crouch_are_on_only_for_exactly_1(sync_client) -> None:
    c = sync_client()
    heights = [c.step("jump 0.5").info["YPos"] for _ in range(5)]
    assert heights == [GROUND] * 5  # "jump 0.5" is "jump off" in Malmo
    heights = [c.step("jump 1").info["YPos"] for _ in range(5)]
    assert max(heights) > GROUND + 1.0


def test_attack_takes_1_or_0_only(server: WorldServer, sync_client) -> None:
    c = sync_client()
    c.step("attack 0.5\nattack 1\nattack 0")
    assert server.status()["ignored_commands"] == 1


def test_continuous_yaw_is_not_wrapped(sync_client) -> None:
    c = sync_client()
    for _ in range(50):  # 2.5 s at 180 degrees per second
        r = c.step("turn 1")
    assert r.info["Yaw"] == 450.0
    r = c.step("turn 0\nsetYaw -400")
    assert c.step("").info["Yaw"] == -400.0


def test_move_ramps_to_full_speed_over_six_ticks(sync_client) -> None:
    c = sync_client()
    z = [c.step("move 1").info["ZPos"]]
    for _ in range(8):
        z.append(c.step("move 1").info["ZPos"])
    steps = [round((b - a) / WALK_SPEED, 3) for a, b in zip(z, z[1:], strict=False)]
    assert steps == [0.444, 0.722, 0.907, 0.985, 1.0, 1.0, 1.0, 1.0]  # 0.167 came first
    assert z[0] - 0.5 == pytest.approx(WALK_SPEED / 6)


def test_discrete_moves_follow_malmo(raw_client) -> None:
    # movenorth ignores its parameter; turn and move use only its sign.
    def discrete_only(xml: str) -> str:
        xml = xml.replace('<ContinuousMovementCommands turnSpeedDegs="180"/>', "")
        return re.sub(r"<DiscreteMovementCommands>.*?</DiscreteMovementCommands>",
                      "<DiscreteMovementCommands/>", xml)  # fmt: skip

    c = raw_client(discrete_only)
    c.step("")
    r = c.step("movenorth 0")
    r = c.step("")
    assert r.info["ZPos"] == -0.5
    c.step("turn 5")  # one quarter, to yaw 90: facing -x
    r = c.step("move 0.2")
    r = c.step("")
    assert (r.info["Yaw"], r.info["XPos"]) == (90.0, -0.5)


def test_simple_craft_needs_no_crafting_table(sync_client) -> None:
    # Coal first: smelting burns fuel from the first slot up, whatever it is (a wooden
    # pickaxe in slot 0 would burn).
    c = sync_client(inventory=((0, "coal", 1), (1, "planks", 3), (2, "stick", 2),
                               (3, "iron_ore", 1)))  # fmt: skip
    c.step("craft wooden_pickaxe\ncraft iron_ingot")
    r = c.step("")
    held = {s["type"] for s in r.info["inventory"]}
    assert {"wooden_pickaxe", "iron_ingot"} <= held


# ----------------------------------------------------------- rewards, quits
def test_quit_description_pays_the_matching_mission_end_reward(raw_client) -> None:
    end = (
        '<RewardForMissionEnd rewardForDeath="-9"><Reward description="Gave_Up" reward="-2"/>'
        '<Reward description="other" reward="7"/></RewardForMissionEnd>'
    )
    c = raw_client(
        lambda x: x.replace("<MissionQuitCommands/>",
                            '<MissionQuitCommands quitDescription="gave_up"/>'),
        rewards=end,
    )  # fmt: skip
    total, r = _total(c, ["", "quit"])
    assert r.done and total == -2.0  # descriptions match without regard to case


def test_death_pays_reward_for_death(sync_client) -> None:
    end = '<RewardForMissionEnd rewardForDeath="-9"><Reward description="x" reward="1"/>'
    c = sync_client(placement=(0.5, GROUND + 40, 0.5), rewards=end + "</RewardForMissionEnd>")
    total, r = _total(c, [""] * 80)
    assert r.done and total == -9.0


def test_command_quota_ends_the_mission(raw_client) -> None:
    quota = (
        '<AgentQuitFromReachingCommandQuota total="5" description="quota">'
        '<Quota commands="turn" quota="2" description="turns"/>'
        "</AgentQuitFromReachingCommandQuota>"
        '<RewardForMissionEnd><Reward description="turns" reward="3"/>'
        '<Reward description="quota" reward="4"/></RewardForMissionEnd>'
    )
    c = raw_client(rewards=quota)
    total, r = _total(c, ["turn 0", "move 1", "turn 0"])  # the second turn: its quota
    assert r.done and total == 3.0
    c2 = raw_client(rewards=quota)
    total, r = _total(c2, ["move 1"] * 5)  # the total: 5 handled commands
    assert r.done and total == 4.0


def test_touch_rewards_follow_their_behaviour(sync_client) -> None:
    floor = '<DrawCuboid x1="-3" y1="3" z1="-3" x2="3" y2="3" z2="8" type="gold_block"/>'
    touch = (
        "<RewardForTouchingBlockType>"
        '<Block type="gold_block" reward="1" behaviour="onceOnly"/>'
        '<Block type="gold_block" reward="10" behaviour="oncePerBlock"/>'
        '<Block type="gold_block" reward="100" behaviour="constant"/>'
        "</RewardForTouchingBlockType>"
    )
    c = sync_client(decorators=floor, rewards=touch)
    total, _ = _total(c, [""] * 3)  # standing on one block for three ticks
    assert total == 1 + 10 + 300


def test_time_taken_and_positions(sync_client) -> None:
    rules = (
        '<RewardForTimeTaken initialReward="0" delta="-1" density="PER_TICK"/>'
        '<RewardForReachingPosition><Marker x="0.5" y="4" z="0.5" tolerance="0.5" reward="5"/>'
        '<Marker x="0.5" y="4" z="0.5" tolerance="0.5" reward="2" oneshot="false"/>'
        "</RewardForReachingPosition>"
    )
    c = sync_client(rewards=rules)
    total, _ = _total(c, [""] * 4)
    assert total == -4 + 5 + 2 * 4


def test_discarding_and_damage_rewards(sync_client) -> None:
    rules = (
        '<RewardForDiscardingItem><Item type="dirt" reward="3"/></RewardForDiscardingItem>'
        '<RewardForDamagingEntity><Mob type="Pig" reward="0.5"/></RewardForDamagingEntity>'
    )
    pig = '<DrawEntity x="0.5" y="4" z="1.6" type="Pig"/>'
    c = sync_client(inventory=((0, "dirt", 5),), rewards=rules, decorators=pig)
    total, r = _total(c, ["discardCurrentItem", "setPitch 40"])
    assert total == 3.0  # one item dropped, not the stack
    assert {s["type"]: s["quantity"] for s in r.info["inventory"]} == {"dirt": 4}
    total, _ = _total(c, ["attack 1", "attack 0"])
    assert total == 0.5  # a bare hand deals 1 damage


def test_chat_is_observed_and_rewarded(raw_client) -> None:
    rules = (
        "<ObservationFromChat/><ObservationFromRecentCommands/>"
        '<RewardForSendingMatchingChatMessage><ChatMatch description="hi" regex="hel+o.*" '
        'reward="2"/></RewardForSendingMatchingChatMessage>'
    )
    c = raw_client(lambda x: x.replace("<MissionQuitCommands/>", "<MissionQuitCommands/>"
                                       "<ChatCommands/>"), rewards=rules)  # fmt: skip
    total, r = _total(c, ["chat hello there\nmove 0"])
    assert total == 2.0
    assert r.info["Chat"] == ["<graft> hello there"]
    assert r.info["CommandsSinceLastObservation"] == ["chat hello there", "move 0"]
    r = c.step("")
    assert "Chat" not in r.info and "CommandsSinceLastObservation" not in r.info


# ----------------------------------------------------------- observations
def test_hotbar_and_distance(sync_client) -> None:
    rules = (
        '<ObservationFromHotBar/><ObservationFromDistance><Marker name="home" x="3.5" y="4" '
        'z="4.5"/></ObservationFromDistance>'
    )
    c = sync_client(rewards=rules, inventory=((2, "log", 7),))
    r = c.step("")
    assert r.info["Hotbar_2_item"] == "log" and r.info["Hotbar_2_size"] == 7
    assert "Hotbar_9_item" not in r.info
    assert r.info["distanceFromhome"] == pytest.approx(5.0)


def test_absolute_grids_read_world_coordinates(raw_client) -> None:
    grid = (
        '<ObservationFromGrid><Grid name="abs" absoluteCoords="true"><min x="9" y="7" z="10"/>'
        '<max x="11" y="7" z="10"/></Grid></ObservationFromGrid>'
    )
    shapes = (
        '<DrawSphere x="10" y="8" z="10" radius="1" type="glowstone"/>'
        '<DrawLine x1="9" y1="7" z1="8" x2="11" y2="7" z2="9" type="oak_stairs"/>'
    )
    c = raw_client(lambda x: re.sub(r"<ObservationFromGrid>.*?</ObservationFromGrid>", grid, x),
                   decorators=shapes)  # fmt: skip
    r = c.step("")
    assert r.info["abs"] == ["air", "glowstone", "air"]  # the sphere's bottom cell


def test_entity_ids_are_uuids_and_ranges_exclusive(sync_client) -> None:
    items = (
        '<DrawItem x="0" y="4" z="16" type="apple"/>'  # 16 blocks away: outside xrange 16
        '<DrawItem x="0" y="4" z="15" type="bread"/>'
    )
    c = sync_client(decorators=items)
    entities = c.step("").info["entities"]
    assert [e["name"] for e in entities] == ["graft", "bread"]
    for e in entities:
        assert str(uuid.UUID(e["id"])) == e["id"]


def test_the_ray_reaches_50_blocks_and_sees_items(sync_client) -> None:
    wall = '<DrawCuboid x1="-3" y1="4" z1="45" x2="3" y2="8" z2="45" type="stone"/>'
    c = sync_client(decorators=wall)
    los = c.step("").info["LineOfSight"]
    assert (los["type"], los["hitType"], los["inRange"]) == ("stone", "block", False)
    assert los["z"] == pytest.approx(45.0) and "blockX" not in los  # the hit point only
    c2 = sync_client(decorators='<DrawItem x="0" y="5" z="3" type="diamond"/>')
    for _ in range(10):  # the item falls onto the ground
        los = c2.step("setPitch 27").info["LineOfSight"]
    assert (los["hitType"], los["type"], los["stackSize"]) == ("item", "diamond", 1)
