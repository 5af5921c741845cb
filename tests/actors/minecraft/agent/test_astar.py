"""The A* travel planner on hand-built maps: optimal costs (computed by hand in each
case), unreachable goals, safety around lava and caves, and re-planning."""

from __future__ import annotations

import numpy as np
import pytest

from actors.minecraft.agent import astar as A

N = 15


def floor_map() -> np.ndarray:
    """Open air over a floor of stone at y=0 (grid indexed [y, z, x])."""
    g = np.zeros((N, N, N), dtype=np.uint8)
    g[0] = A.SOLID
    return g


def test_open_floor_costs_one_per_block() -> None:
    p = A.plan(floor_map(), (2, 1, 7), [(12, 1, 7)])
    assert p.reached and p.cost == 10.0
    assert all(s.kind == "move" for s in p.steps) and len(p.steps) == 10


def test_one_block_wall_is_jumped() -> None:
    g = floor_map()
    g[1, :, 6] = A.HARD  # unbreakable, one block high, across the whole map
    p = A.plan(g, (2, 1, 7), [(12, 1, 7)])
    # 3 walks to x=5, jump onto x=6 (2), drop to x=7 (1), 5 walks: 3 + 2 + 1 + 5.
    assert p.reached and p.cost == 11.0
    assert A.Step("move", (6, 2, 7)) in p.steps
    assert p.destroyed == ()


def test_two_block_wall_is_dug_through_once() -> None:
    g = floor_map()
    g[1:3, :, 6] = A.SOLID  # breakable, two blocks high
    p = A.plan(g, (2, 1, 7), [(12, 1, 7)])
    # Cheapest: break the top block (5) and jump onto the bottom one (2) rather than
    # breaking both (10) and walking: 3 + 5 + 2 + 1 + 5.
    assert p.reached and p.cost == 16.0
    assert p.destroyed == ((6, 2, 7),)


def test_tunnel_through_rock() -> None:
    g = np.full((N, N, N), A.SOLID, dtype=np.uint8)
    g[7:9, 7, 7] = A.FREE  # the agent's own two cells
    p = A.plan(g, (7, 7, 7), [(10, 7, 7)])
    # Each block forward: head (5) + feet (5) + move (1).
    assert p.reached and p.cost == 33.0
    assert len(p.destroyed) == 6


def test_dig_down_costs_six_per_level() -> None:
    g = np.full((N, N, N), A.SOLID, dtype=np.uint8)
    g[7:9, 7, 7] = A.FREE
    p = A.plan(g, (7, 7, 7), [(7, 3, 7)])
    assert p.reached and p.cost == 24.0
    assert p.destroyed == ((7, 6, 7), (7, 5, 7), (7, 4, 7), (7, 3, 7))


@pytest.mark.parametrize(
    "build",
    [
        # A bedrock wall three blocks high (too high to jump, unbreakable).
        lambda g: g.__setitem__((slice(1, N), slice(None), 6), A.HARD),
        # The goal on an island in a lava lake.
        lambda g: (
            g.__setitem__((0, slice(None), slice(8, N)), A.LAVA),
            g.__setitem__((0, 7, 12), A.SOLID),
        ),
        # The goal sealed in bedrock.
        lambda g: (
            g.__setitem__((slice(1, 4), slice(6, 9), slice(11, 14)), A.HARD)
            or g.__setitem__((slice(1, 3), 7, 12), A.FREE)
        ),
    ],
    ids=["bedrock-wall", "lava-island", "bedrock-box"],
)
def test_unreachable_goal(build) -> None:
    g = floor_map()
    build(g)
    p = A.plan(g, (2, 1, 7), [(12, 1, 7)])
    assert not p.reached
    assert p.cost < A.plan(floor_map(), (2, 1, 7), [(12, 1, 7)]).cost  # a partial plan


def test_never_breaks_a_block_touching_lava() -> None:
    g = floor_map()
    g[1:3, :, 6] = A.SOLID  # a wall...
    g[3, :, 6] = A.SOLID
    g[4, :, 6] = A.SOLID
    g[2, 3:12, 7] = A.LAVA  # ...with lava behind its upper half in the middle
    p = A.plan(g, (2, 1, 7), [(12, 1, 7)])
    assert p.reached
    for c in p.destroyed:
        x, y, z = c
        for dx, dy, dz in A.NEIGHBOURS6:
            assert g[y + dy, z + dz, x + dx] != A.LAVA
    # No jump possible (wall 4 high): dig a 2-high hole where lava does not touch it,
    # at z <= 2 or z >= 12, i.e. a detour of 5 blocks each way (10) + 2 digs (10) + 10.
    assert p.cost == 30.0


@pytest.mark.parametrize(
    ("below", "ok"),
    [("cave", False), ("lava", False), ("step", True)],
)
def test_dig_down_only_when_the_fall_is_safe(below: str, ok: bool) -> None:
    g = np.full((N, N, N), A.SOLID, dtype=np.uint8)
    g[7:9, 7, 7] = A.FREE
    if below == "cave":
        g[1:6, 7, 7] = A.FREE  # a 5-deep shaft under the floor block: a fall of 5
    elif below == "lava":
        g[5, 7, 7] = A.LAVA
    else:
        g[4:6, 7, 7] = A.FREE  # a fall of 2, safe
    # In solid rock an unreachable goal would have the search dig everywhere: a budget.
    p = A.plan(g, (7, 7, 7), [(7, 6, 7), (7, 5, 7), (7, 4, 7)], max_expansions=1500)
    assert p.reached is ok
    if not ok:
        assert (7, 6, 7) not in p.destroyed


def test_replans_when_a_block_appears() -> None:
    g = floor_map()
    planner = A.Planner()
    first = planner(g, (2, 1, 7), [(12, 1, 7)])
    assert planner(g, (2, 1, 7), [(12, 1, 7)]) is first  # unchanged world: memoised
    assert planner.searches == 1
    # A bedrock pillar appears right on the straight path.
    g2 = g.copy()
    g2[1:N, 7, 5] = A.HARD
    second = planner(g2, (2, 1, 7), [(12, 1, 7)])
    assert planner.searches == 2
    assert second.reached and second.cost == 12.0  # a side step and back: 10 + 2
    assert all(s.cell != (5, 1, 7) for s in second.steps)


def test_state_chain_stores_one_change_per_node() -> None:
    g = np.full((N, N, N), A.SOLID, dtype=np.uint8)
    g[7:9, 7, 7] = A.FREE
    search = A._Search(g, frozenset({(9, 7, 7)}), 2)
    root = A._Node(None, (7, 7, 7), None, 0.0, 0)
    kids = search.successors(root)
    east = next(k for k in kids if k.pos == (8, 7, 7))
    # The arrival node changed only the position; its parents each destroyed one block.
    assert east.broken is None and east.parent is not None
    assert east.parent.broken is not None and east.parent.parent.broken is not None
    assert east.parent.parent.parent is root
    assert east.destroyed(search.index((8, 8, 7))) and east.destroyed(search.index((8, 7, 7)))
    assert not root.destroyed(search.index((8, 7, 7)))


def test_kept_heuristic_and_breakable_flags_match_their_definitions() -> None:
    """The per-position cache of h and the precomputed breakable flags give what the
    definitions give: h = min over goals of the move bound + 5 per solid goal cell not
    destroyed on the way; breakable = solid with no water or lava among its 6 neighbours."""
    rng = np.random.default_rng(7)
    for _ in range(20):
        g = rng.choice(
            [A.FREE, A.SOLID, A.HARD, A.WATER, A.LAVA], (N, N, N), p=[0.4, 0.4, 0.1, 0.05, 0.05]
        )
        g = g.astype(np.uint8)
        goals = frozenset(tuple(int(v) for v in rng.integers(-1, N + 1, 3)) for _ in range(6))
        search = A._Search(g, goals, 4)
        for c in np.ndindex(N, N, N):
            liquid = any(
                0 <= c[0] + d[0] < N and 0 <= c[1] + d[1] < N and 0 <= c[2] + d[2] < N
                and g[c[1] + d[1], c[2] + d[2], c[0] + d[0]] in (A.WATER, A.LAVA)
                for d in A.NEIGHBOURS6
            )  # fmt: skip
            assert search.breakable(c) == (g[c[1], c[2], c[0]] == A.SOLID and not liquid)
        # Nodes that destroyed goal cells, other solid cells, or nothing.
        goal_cells = [c for gl in goals for c in (gl, (gl[0], gl[1] + 1, gl[2]))]
        for _ in range(50):
            node = A._Node(None, tuple(int(v) for v in rng.integers(0, N, 3)), None, 0.0, 0)
            for _ in range(int(rng.integers(0, 4))):
                c = goal_cells[int(rng.integers(len(goal_cells)))] if rng.random() < 0.5 else (
                    tuple(int(v) for v in rng.integers(0, N, 3))
                )  # fmt: skip
                i = search.index(c)
                if i >= 0 and search.cat(c, node) == A.SOLID:  # as the search breaks blocks
                    node = A._Node(node, node.pos, i, node.g + 5, 0)
            node = A._Node(node, tuple(int(v) for v in rng.integers(0, N, 3)), None, node.g, 0)
            expected = min(
                A.heuristic(node.pos, gl)
                + 5.0 * sum(search.cat(c, node) == A.SOLID for c in (gl, (gl[0], gl[1] + 1, gl[2])))
                for gl in goals
            )
            assert search.h(node) == expected
