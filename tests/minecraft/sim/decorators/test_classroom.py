"""ClassroomDecorator: the building's rooms, the path of obstacles from the start room to
the goal room, and the blocks drawn for them, on Malmo's sample specifications."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from minecraft import blocks as B
from minecraft.malmo.mission import parse_mission
from minecraft.sim.decorators import classroom
from minecraft.sim.world import World

SAMPLES = Path(__file__).parents[2] / "compat" / "missions" / "malmo_samples"


def _spec_xml(
    *, width: int = 7, height: int = 7, length: int = 7, path: int = 0, sn: int = 0,
    ew: int = 0, ab: int = 0, gap: int = 0, bridge: int = 0, door: int = 0, puzzle: int = 0,
    jump: int = 0, stairs: int = 0, ladder: int = 0, vjump: int = 0, seed: str = "5",
    hint: str = "1",
) -> str:  # fmt: skip
    return f"""<Mission xmlns="http://ProjectMalmo.microsoft.com">
  <About><Summary>rooms</Summary></About>
  <ServerSection><ServerHandlers>
    <FlatWorldGenerator generatorString="3;7,60*1,2;1;"/>
    <ClassroomDecorator seed="{seed}"><specification>
      <width>{width}</width><height>{height}</height><length>{length}</length>
      <pathLength>{path}</pathLength>
      <divisions><southNorth>{sn}</southNorth><eastWest>{ew}</eastWest>
        <aboveBelow>{ab}</aboveBelow></divisions>
      <horizontalObstacles><gap>{gap}</gap><bridge>{bridge}</bridge><door>{door}</door>
        <puzzle>{puzzle}</puzzle><jump>{jump}</jump></horizontalObstacles>
      <verticalObstacles><stairs>{stairs}</stairs><ladder>{ladder}</ladder>
        <jump>{vjump}</jump></verticalObstacles>
      <hintLikelihood>{hint}</hintLikelihood>
    </specification></ClassroomDecorator>
  </ServerHandlers></ServerSection>
  <AgentSection mode="Survival"><Name>A</Name>
    <AgentStart><Placement x="-203.5" y="81" z="217.5"/></AgentStart>
    <AgentHandlers><ObservationFromFullStats/><ContinuousMovementCommands/></AgentHandlers>
  </AgentSection>
</Mission>"""


def _sample(name: str) -> classroom.Building:
    spec = parse_mission((SAMPLES / name).read_text()).classroom
    assert spec is not None
    return classroom.layout(spec, world_seed=1)


def _inside(room: classroom.Room, x: float, y: float, z: float) -> bool:
    return (room.x <= x < room.x + room.width and room.y <= y < room.y + room.height
            and room.z <= z < room.z + room.length)  # fmt: skip


def _joined(b: classroom.Building) -> set[int]:
    """Rooms reachable from the start room through doors, gaps... (obstacle dividers)."""
    seen, todo = {id(b.start_room)}, [b.start_room]
    while todo:
        room = todo.pop()
        for d in b.obstacles:
            for a, c in ((d.room_in, d.room_out), (d.room_out, d.room_in)):
                if a is room and id(c) not in seen:
                    seen.add(id(c))
                    todo.append(c)
    return seen


def test_one_room_holds_the_start_and_the_goal() -> None:
    b = _sample("findthegoal.xml")
    (room,) = b.rooms
    assert b.start_room is b.goal_room is room and b.path == ()
    assert (room.x, room.y, room.z, room.width, room.height, room.length) == (0, 55, 0, 7, 4, 7)
    assert _inside(room, *b.goal) and _inside(room, b.start[0], b.start[1] - 1, b.start[2])


@pytest.mark.parametrize("name", ["obstacles.xml", "attic.xml", "vertical.xml"])
def test_the_path_leads_room_by_room_from_start_to_goal(name: str) -> None:
    b = _sample(name)
    spec_path = {"obstacles.xml": 4, "attic.xml": 2, "vertical.xml": 2}[name]
    assert len(b.path) == min(spec_path, len(b.rooms) - 1)
    assert b.path[0].room_in is b.start_room and b.path[-1].room_out is b.goal_room
    assert all(a.room_out is c.room_in for a, c in zip(b.path, b.path[1:], strict=False))
    assert len({id(d.room_out) for d in b.path} | {id(b.start_room)}) == len(b.path) + 1
    assert _joined(b) == {id(r) for r in b.rooms}  # orphan rooms are joined too
    assert _inside(b.goal_room, *b.goal)


def test_the_obstacles_on_the_path_are_the_ones_the_specification_counts() -> None:
    # Four walls to pass, one of each horizontal obstacle: each is drawn once.
    b = _sample("obstacles.xml")
    assert len(b.rooms) == 5 and all(d.kind == "SouthNorth" for d in b.path)
    assert Counter(d.obstacle for d in b.path) == {"Gap": 1, "Bridge": 1, "Door": 1, "Puzzle": 1}
    # Two floors to climb: one staircase, one ladder.
    v = _sample("vertical.xml")
    assert [r.y for r in v.rooms] == [55, 61, 67]
    assert Counter(d.obstacle for d in v.path) == {"Stairs": 1, "Ladder": 1}


def test_a_gap_is_a_two_block_opening_with_a_hint_below() -> None:
    mission = parse_mission(_spec_xml(length=15, path=1, sn=1, gap=1))
    w = World(mission, 1)
    assert mission.classroom is not None
    b = classroom.layout(mission.classroom, world_seed=1)
    (d,) = b.path
    assert d.obstacle == "Gap" and (b.rooms[0].z, b.rooms[1].z) == (0, 8)
    wall = [[B.NAMES[w.get(x, y, 7)] for x in range(7)] for y in range(55, 59)]
    open_x = [x for x in range(7) if all(row[x] == "air" for row in wall[:3])]
    assert len(open_x) == 2 and open_x[1] == open_x[0] + 1
    assert all(row[x] == "cobblestone" for row in wall for x in range(7) if x not in open_x)
    assert {wall[3][x] for x in open_x} == {"torch"}  # lit from above, as in Java
    assert {B.NAMES[w.get(x, 54, 7)] for x in open_x} == {"gold_ore"}  # the hint


def test_the_world_has_the_goal_and_the_agent_in_the_start_room() -> None:
    mission = parse_mission((SAMPLES / "obstacles.xml").read_text())
    w = World(mission, 1)
    b = _sample("obstacles.xml")
    assert w.get(*b.goal) == B.ID["gold_block"]  # the default (dungeon) palette's goal
    p = w.player.body
    assert (p.x, p.y, p.z) == b.start and _inside(b.start_room, p.x, p.y - 1, p.z)


def test_an_unparsable_seed_follows_the_world_seed() -> None:
    spec = parse_mission(_spec_xml(seed="__SEED__", length=30, sn=3, path=2, gap=1)).classroom
    assert spec is not None
    assert classroom.layout(spec, world_seed=4) == classroom.layout(spec, world_seed=4)
    assert len({classroom.layout(spec, world_seed=s).goal for s in range(8)}) > 1


_COMPLEXITY = """<Mission xmlns="http://ProjectMalmo.microsoft.com">
  <About><Summary>c</Summary></About>
  <ServerSection><ServerHandlers><FlatWorldGenerator generatorString="3;7,60*1,2;1;"/>
    <ClassroomDecorator seed="{seed}" palette="random"><complexity>
      <building>1</building><path>0.5</path><division>1</division><obstacle>1</obstacle>
      <hint>0.5</hint></complexity></ClassroomDecorator>
  </ServerHandlers></ServerSection>
  <AgentSection mode="Survival"><Name>A</Name>
    <AgentStart><Placement x="0" y="80" z="0"/></AgentStart>
    <AgentHandlers><ObservationFromFullStats/></AgentHandlers></AgentSection>
</Mission>"""


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_complexity_buildings_join_every_room_to_the_path(seed: int) -> None:
    spec = parse_mission(_COMPLEXITY.format(seed=seed)).classroom
    assert spec is not None and spec.complexity == (1.0, 0.5, 1.0, 1.0, 0.5)
    b = classroom.layout(spec, world_seed=0)
    assert len(b.rooms) > 1 and _joined(b) == {id(r) for r in b.rooms}
    assert _inside(b.goal_room, *b.goal)
    assert b.palette["goal"] in ("gold_block", "diamond_block", "redstone_block")
