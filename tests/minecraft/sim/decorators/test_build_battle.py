"""BuildBattleDecorator and RewardForStructureCopying: the copy is scored against the goal
structure as blocks are placed and broken in it, as Malmo's Java scores it."""

from __future__ import annotations

import pytest

from minecraft import blocks as B
from minecraft.malmo.mission import MissionError, parse_mission
from minecraft.sim import support
from minecraft.sim.world import World

# The goal: lapis at (0,5,0) and (1,5,0). The copy area (4..5, 5, 1) starts with the
# first lapis in place. The agent stands south of the copy, looking north and down at
# the floor in front of the missing block's cell (5, 5, 1).
_XML = """<Mission xmlns="http://ProjectMalmo.microsoft.com">
  <About><Summary>copy</Summary></About>
  <ServerSection><ServerHandlers>
    <FlatWorldGenerator generatorString="3;7,3*3,89;1;"/>
    <BuildBattleDecorator>
      <PlayerStructureBounds><min x="4" y="5" z="1"/><max x="5" y="5" z="1"/>
      </PlayerStructureBounds>
      <GoalStructureBounds><min x="0" y="5" z="0"/><max x="1" y="5" z="0"/></GoalStructureBounds>
      {marks}
    </BuildBattleDecorator>
    <DrawingDecorator>
      <DrawCuboid type="lapis_block" x1="0" x2="1" y1="5" y2="5" z1="0" z2="0"/>
      <DrawBlock type="lapis_block" x="4" y="5" z="1"/>
    </DrawingDecorator>
  </ServerHandlers></ServerSection>
  <AgentSection mode="{mode}"><Name>Agent0</Name>
    <AgentStart>
      <Placement x="5.5" y="5" z="2.5" yaw="180" pitch="60"/>
      <Inventory><InventoryBlock slot="0" type="lapis_block" quantity="1"/>
        <InventoryBlock slot="1" type="dirt" quantity="1"/></Inventory>
    </AgentStart>
    <AgentHandlers>
      <DiscreteMovementCommands/><InventoryCommands/>
      <RewardForStructureCopying rewardScale="2" rewardForCompletion="10" {dist}>
        <RewardDensity>PER_BLOCK</RewardDensity>
        <AddQuitProducer description="copied"/>
      </RewardForStructureCopying>
    </AgentHandlers>
  </AgentSection>
</Mission>"""
_MARKS = (
    '<BlockTypeOnCorrectPlacement type="gold_block"/>'
    '<BlockTypeOnIncorrectPlacement type="redstone_block"/>'
)


def _world(*, marks: str = "", mode: str = "Survival", dist: str = "") -> World:
    return World(parse_mission(_XML.format(marks=marks, mode=mode, dist=dist)), 1)


def _step(w: World, command: str) -> float:
    w.tick([command])
    reward, w.pending_reward = w.pending_reward, 0.0
    return reward


def test_placing_the_missing_block_pays_the_scale_and_the_completion_once() -> None:
    w = _world()
    assert _step(w, "") == 0.0  # the first scoring sets the baseline: 1 right block
    assert _step(w, "use 1") == 2.0 + 10.0  # one more right block: the copy is complete
    assert w.get(5, 5, 1) == B.ID["lapis_block"] and w.done and w.quit_codes == ["copied"]
    assert w.player.inventory.count("lapis_block") == 0  # Survival: the block is used up


def test_removing_a_right_block_costs_the_scale_and_completion_is_paid_once() -> None:
    xml = _XML.format(marks="", mode="Creative", dist="")
    w = World(parse_mission(xml.replace('<AddQuitProducer description="copied"/>', "")), 1)
    assert _step(w, "") == 0.0
    assert _step(w, "use 1") == 2.0 + 10.0
    assert _step(w, "attack 1") == -2.0 and w.get(5, 5, 1) == B.AIR
    assert _step(w, "use 1") == 2.0  # complete again: no second bonus
    assert not w.done


def test_a_wrong_block_costs_the_scale_and_is_marked() -> None:
    w = _world(marks=_MARKS)
    assert _step(w, "") == 0.0
    # The right lapis of the copy and of the goal are marked gold at the first scoring.
    assert w.get(4, 5, 1) == w.get(0, 5, 0) == B.ID["gold_block"]
    assert w.get(1, 5, 0) == B.ID["lapis_block"]
    assert _step(w, "hotbar.2 1") == 0.0
    assert _step(w, "use 1") == -2.0
    assert w.get(5, 5, 1) == B.ID["redstone_block"]  # the wrong dirt, marked
    assert _step(w, "attack 1") == 2.0 and w.get(5, 5, 1) == B.AIR


def test_the_goal_structure_cannot_be_broken() -> None:
    w = _world()
    w.player.body.x, w.player.body.z = 1.5, 1.5  # south of the goal's (1, 5, 0)
    _step(w, "attack 1")
    assert w.get(1, 5, 0) == B.ID["lapis_block"]


def test_creative_mode_keeps_the_placed_block_in_the_inventory() -> None:
    w = _world(mode="Creative")
    _step(w, "use 1")
    assert w.get(5, 5, 1) == B.ID["lapis_block"]
    assert w.player.inventory.count("lapis_block") == 1


def test_the_reward_is_shared_as_the_distribution_says() -> None:
    # Only this agent's share: 0.5 of 2 + 10.
    w = _world(dist='rewardDistribution="Agent0:0.5 Agent1:-0.1"')
    _step(w, "")
    assert _step(w, "use 1") == 6.0


def test_bounds_of_different_volumes_are_refused() -> None:
    xml = _XML.format(marks="", mode="Survival", dist="").replace(
        '<max x="5" y="5" z="1"/>', '<max x="6" y="5" z="1"/>'
    )
    with pytest.raises(MissionError, match="hold 2 and 3 blocks"):
        support.check(parse_mission(xml))
