"""A short stage of the tree against a real world server process in synchronous mode:
walk to a tree, chop a log, craft planks, all through the MalmoEnv protocol."""

from __future__ import annotations

import time

import pytest

from minecraft.agent.diamond_tree import run_episode
from minecraft.agent.tree_profile import TimeProfile
from minecraft.agent.watchdog import IDLE_TICKS
from minecraft.malmo.client import MalmoClient
from minecraft.sim.pool import ServerPool
from minecraft.sim.server import WorldServer
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


def test_a_second_iron_pickaxe_keeps_its_sticks_through_smelting(server: WorldServer) -> None:
    """The iron pickaxe wore out in the mine: ore, coal and the last wood in hand. The
    world burns fuel from the first slot up; the tree puts the coal there first, so the
    sticks in slot 0 are left for the new pickaxe (it used to burn them and then wait
    for a log forever)."""
    inventory = (
        (0, "stick", 2), (1, "planks", 1), (2, "wooden_pickaxe", 1), (3, "coal", 1),
        (4, "iron_ore", 3), (5, "furnace", 1), (6, "stone_pickaxe", 1),
    )  # fmt: skip
    client = MalmoClient("127.0.0.1", server.port, synchronous=True, timeout=10)
    client.init(flat_mission(inventory=inventory, grid_radius=7, ms_per_tick=50))
    try:
        result = run_episode(
            client, seed=3, max_ticks=300, stop_when=lambda p: p.count("iron_pickaxe") > 0
        )
    finally:
        client.close()
    assert result.end == "stopped", result
    assert result.reached["iron_pickaxe"] < 100
    assert result.watchdog == 0


def test_the_watchdog_fires_on_a_tree_that_cannot_progress(server: WorldServer) -> None:
    """Shut in bedrock with no wood: nothing can be planned, no leaf acts. The watchdog
    fires every IDLE_TICKS ticks without progress and the profile counts each firing."""
    deco = (
        '<DrawCuboid x1="-1" y1="3" z1="-1" x2="1" y2="6" z2="1" type="bedrock"/>'
        '<DrawCuboid x1="0" y1="4" z1="0" x2="0" y2="5" z2="0" type="air"/>'
    )
    client = MalmoClient("127.0.0.1", server.port, synchronous=True, timeout=10)
    client.init(flat_mission(decorators=deco, grid_radius=7, ms_per_tick=50))
    profile = TimeProfile()
    try:
        result = run_episode(client, seed=3, max_ticks=3 * IDLE_TICKS + 50, profile=profile)
    finally:
        client.close()
    assert result.watchdog == 3
    assert sum(profile.summary().watchdog.values()) == 3
    assert profile.summary().longest_wait >= 3 * IDLE_TICKS
