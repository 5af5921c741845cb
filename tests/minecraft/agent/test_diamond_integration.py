"""A short stage of the tree against a real world server process in synchronous mode:
walk to a tree, chop a log, craft planks, all through the MalmoEnv protocol."""

from __future__ import annotations

import time

import pytest

from minecraft.agent.diamond_tree import run_episode
from minecraft.malmo.client import MalmoClient
from minecraft.sim.pool import ServerPool
from tests.minecraft.conftest import flat_mission

pytestmark = pytest.mark.service  # real server processes, or Ray


def _pool() -> ServerPool:
    """A started one-server pool. Port 0 picks a free port and releases it before the
    server binds it; on a busy machine another process can take it in between, so try a
    few times."""
    for attempt in range(3):
        pool = ServerPool(1, 0, seed=3)
        try:
            pool.start()
            return pool
        except (RuntimeError, TimeoutError, OSError):
            pool.stop()
            if attempt == 2:
                raise
    raise AssertionError("unreachable")


@pytest.mark.parametrize("ticks_per_step", [1, 6])
def test_gathers_a_log_and_crafts_planks(ticks_per_step: int) -> None:
    """Every tick, and on a slow client holding each decision for 6 ticks (its aiming
    and steering sized to the hold, ``Commands.hold``)."""
    # A two-block-high trunk 4 blocks east, a one-block wall to jump on the way.
    deco = (
        '<DrawCuboid x1="4" y1="4" z1="0" x2="4" y2="6" z2="0" type="log"/>'
        '<DrawCuboid x1="2" y1="4" z1="-3" x2="2" y2="4" z2="3" type="stone"/>'
    )
    mission = flat_mission(decorators=deco, grid_radius=7, ms_per_tick=50)
    pool = _pool()
    try:
        client = MalmoClient("127.0.0.1", pool.ports[0], synchronous=True, timeout=10)
        client.init(mission)
        t0 = time.perf_counter()
        result = run_episode(
            client,
            seed=3,
            goal="planks",
            max_ticks=600,
            stop_when=lambda p: p.count("planks") >= 4,
            ticks_per_step=ticks_per_step,
        )
        client.close()
    finally:
        pool.stop()
    assert result.end == "stopped", result
    assert result.reached["log"] < result.reached["planks"] < 600
    assert result.deaths == 0
    assert time.perf_counter() - t0 < 20
