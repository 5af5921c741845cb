"""MazeDecorator: what a generated maze guarantees, on small mazes that can be checked by
hand, and the world, start and quit it gives a mission."""

from __future__ import annotations

import json
from collections import deque

import pytest

from minecraft import blocks as B
from minecraft.malmo.mission import MissionError, parse_mission
from minecraft.sim import support
from minecraft.sim.decorators import maze
from minecraft.sim.observe import info_json
from minecraft.sim.world import World


def _xml(
    *, width: int = 5, length: int = 4, scale: int = 1, gaps: str = "0.5", seed: str = "7",
    start: str = 'fixedToEdge="true"', end: str = 'fixedToEdge="true"', extra: str = "",
) -> str:  # fmt: skip
    return f"""<Mission xmlns="http://ProjectMalmo.microsoft.com">
  <About><Summary>maze</Summary></About>
  <ServerSection><ServerHandlers>
    <FlatWorldGenerator generatorString="3;7,2*3,2;1;"/>
    <MazeDecorator>
      <SizeAndPosition length="{length}" width="{width}" scale="{scale}" yOrigin="3"
                       xOrigin="-2" zOrigin="1" height="6"/>
      <GapProbability>{gaps}</GapProbability>
      <Seed>{seed}</Seed>
      <AllowDiagonalMovement>false</AllowDiagonalMovement>
      <StartBlock {start} type="emerald_block" height="1"/>
      <EndBlock {end} type="redstone_block" height="2"/>
      <PathBlock type="stone" height="1"/>
      <FloorBlock type="glowstone"/>
      <GapBlock type="air" height="1"/>
      {extra}
    </MazeDecorator>
  </ServerHandlers></ServerSection>
  <AgentSection mode="Survival"><Name>A</Name>
    <AgentStart><Placement x="100.5" y="4" z="100.5" yaw="90"/></AgentStart>
    <AgentHandlers><ObservationFromFullStats/><ContinuousMovementCommands/></AgentHandlers>
  </AgentSection>
</Mission>"""


def _reachable(open_cells: set[tuple[int, int]], start: tuple[int, int]) -> set:
    seen, todo = {start}, deque([start])
    while todo:
        x, z = todo.popleft()
        for n in ((x + 1, z), (x - 1, z), (x, z + 1), (x, z - 1)):
            if n in open_cells and n not in seen:
                seen.add(n)
                todo.append(n)
    return seen


@pytest.mark.parametrize("seed", ["1", "7", "4711", "123456789"])
def test_a_path_joins_start_and_end_through_open_cells(seed: str) -> None:
    spec = parse_mission(_xml(seed=seed)).maze
    assert spec is not None
    m = maze.layout(spec, world_seed=0)
    assert len(m.open) == 5 * 4 - int(5 * 4 * 0.5)  # exactly the gaps asked for: 10 of 20
    assert m.start[1] == 0 and m.end[1] == 3  # fixedToEdge: first and last row
    assert m.end in _reachable(m.open, m.start)
    # The optimal path is a shortest 4-connected walk of open cells from start to end.
    assert m.path[0] == m.start and m.path[-1] == m.end
    assert all(c in m.open for c in m.path)
    steps = zip(m.path, m.path[1:], strict=False)
    assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1 for a, b in steps)


def test_no_gaps_leaves_every_cell_open_and_the_same_seed_the_same_maze() -> None:
    spec = parse_mission(_xml(gaps="0")).maze
    assert spec is not None
    assert len(maze.layout(spec, world_seed=0).open) == 20
    spec = parse_mission(_xml(gaps="0.6", seed="99")).maze
    assert spec is not None
    assert maze.layout(spec, world_seed=0) == maze.layout(spec, world_seed=5)


def test_a_random_seed_follows_the_world_seed() -> None:
    spec = parse_mission(_xml(seed="random", width=8, length=8)).maze
    assert spec is not None
    assert maze.layout(spec, world_seed=3) == maze.layout(spec, world_seed=3)
    assert len({maze.layout(spec, world_seed=s).open for s in range(6)}) > 1


def test_the_world_has_the_blocks_the_xml_names_and_the_agent_on_the_start() -> None:
    mission = parse_mission(_xml(scale=2))
    w = World(mission, 1)
    assert mission.maze is not None
    m = maze.layout(mission.maze, world_seed=1)
    x0, y0, z0 = -2, 3, 1
    for (cx, cz), (name, height) in ((m.start, ("emerald_block", 1)),
                                     (m.end, ("redstone_block", 2))):  # fmt: skip
        for dx in range(2):  # scale 2: each cell is 2x2 blocks
            for dz in range(2):
                x, z = x0 + 2 * cx + dx, z0 + 2 * cz + dz
                assert w.get(x, y0, z) == B.ID["glowstone"]  # the floor
                col = [B.NAMES[w.get(x, y0 + k, z)] for k in range(1, height + 2)]
                assert col == [name] * height + ["air"]
    gap = next((x, z) for x in range(5) for z in range(4) if (x, z) not in m.open)
    assert w.get(x0 + 2 * gap[0], y0 + 1, z0 + 2 * gap[1]) == B.AIR
    # Malmo moves every agent onto the start block, keeping the yaw the XML gives.
    b = w.player.body
    assert (b.x, b.y, b.z) == (x0 + 2 * (m.start[0] + 0.5), y0 + 2, z0 + 2 * (m.start[1] + 0.5))
    assert w.player.yaw == 90


def test_add_quit_producer_ends_the_mission_on_the_end_block() -> None:
    mission = parse_mission(_xml(extra='<AddQuitProducer description="solved"/>'))
    w = World(mission, 1)
    (q,) = w.mission.rules.quit_positions
    assert mission.maze is not None
    m = maze.layout(mission.maze, world_seed=1)
    assert (q.x, q.y, q.z, q.tolerance, q.description) == (
        -2 + m.end[0] + 0.5,
        3 + 1 + 1,
        1 + m.end[1] + 0.5,
        1.0,
        "solved",
    )
    w.player.body.x, w.player.body.y, w.player.body.z = q.x, q.y, q.z
    w.tick([])
    assert w.done and w.quit_codes == ["solved"]


def test_navigation_observations_point_along_the_path() -> None:
    mission = parse_mission(_xml(gaps="0", extra="<AddNavigationObservations/>"))
    w = World(mission, 1)
    points = w.mission.subgoals
    assert mission.maze is not None
    m = maze.layout(mission.maze, world_seed=1)
    # With no gaps the smoothed path is the straight line start -> end.
    assert [(p.x, p.z) for p in points] == [
        (-2 + c[0] + 0.5, 1 + c[1] + 0.5) for c in (m.start, m.end)
    ]
    obs = json.loads(info_json(w))
    # The start point is under the agent (within its tolerance): the next is the end.
    assert obs["nextSubgoal"]["description"] == "MazeSubpoint_2"
    assert -1.0 <= obs["yawDelta"] <= 1.0


def test_diagonal_mazes_and_waypoints() -> None:
    extra = '<Waypoints quantity="3"><WaypointItem type="apple"/></Waypoints>'
    xml = _xml(width=9, length=9, gaps="0.6", extra=extra).replace(
        "<AllowDiagonalMovement>false", "<AllowDiagonalMovement>true"
    )
    mission = parse_mission(xml)
    assert mission.maze is not None
    m = maze.layout(mission.maze, world_seed=3)
    steps = zip(m.path, m.path[1:], strict=False)
    assert all(max(abs(a[0] - b[0]), abs(a[1] - b[1])) == 1 for a, b in steps)
    assert len(m.waypoints) == 3 and m.waypoints <= m.open and m.end not in m.waypoints
    w = World(mission, 3)
    assert sorted(it.item for it in w.items) == ["apple"] * 3  # one on each waypoint


def test_a_maze_too_large_for_a_world_is_refused() -> None:
    with pytest.raises(MissionError, match="simulator builds mazes of 1 to 512 blocks"):
        support.check(parse_mission(_xml(width=300, scale=2)))
