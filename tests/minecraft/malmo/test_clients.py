"""The published malmoenv client (0.0.8, unchanged) and graft's client against a real
``minecraft serve`` process with real Malmo's timing; reconnection after the server goes
away."""

from __future__ import annotations

import warnings
from collections.abc import Iterator

import numpy as np
import pytest

from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission_xml import SAMPLE_PATH, mission_xml, obtain_diamond
from minecraft.sim.pool import ServerPool
from minecraft.sim.server import WorldServer
from tests.minecraft.conftest import FAST


@pytest.fixture(scope="module")
def pool() -> Iterator[ServerPool]:
    with ServerPool(1, base_port=0, seed=11, ms_per_tick=10, timing=FAST) as p:
        yield p


MISSION = mission_xml(width=32, height=24, ms_per_tick=10, seed=5)


@pytest.mark.service
def test_unchanged_malmoenv_client(pool: ServerPool) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import malmoenv
    env = malmoenv.make()
    env.init(MISSION, pool.ports[0], reshape=True)
    obs = env.reset()
    assert obs.shape == (24, 32, 3) and obs.dtype == np.uint8 and obs.any()
    infos = []
    for a in range(6):
        obs, reward, done, info = env.step(a % 3)
        assert obs.shape == (24, 32, 3) and not done
        infos.append(info)
    # Frames come faster than ticks: a step may bring no observation (as from Malmo).
    assert all(i == "" or ('"TotalTime"' in i and '"cube"' in i) for i in infos)
    assert any(infos)
    env.close()


@pytest.mark.service
def test_graft_client_same_test(pool: ServerPool) -> None:
    c = MalmoClient("127.0.0.1", pool.ports[0])
    c.init(MISSION)
    frame = c.reset()
    assert frame.shape == (24, 32, 3) and frame.dtype == np.uint8 and frame.any()
    for cmd in ("move 1", "turn 1", "attack 1"):
        r = c.step(cmd)
        assert r.frame.shape == (24, 32, 3) and not r.done
        assert r.info == {} or len(r.info["cube"]) == 15**3
    assert len(c.observe().info["cube"]) == 15**3
    r2 = c.reset()  # quits the running episode and starts the next
    assert r2.shape == (24, 32, 3)
    c.close()


@pytest.mark.service
def test_sample_mission_parses_and_runs(pool: ServerPool) -> None:
    assert SAMPLE_PATH.read_text() == obtain_diamond()  # the file is the builder's output
    c = MalmoClient("127.0.0.1", pool.ports[0], synchronous=True)
    c.init(SAMPLE_PATH.read_text())
    assert c.reset().shape == (64, 64, 3)
    assert c.step("craft planks").info["IsAlive"] is True
    c.close()


@pytest.mark.serial  # a port reused across a restart, or pacing
def test_reset_reconnects_after_the_server_restarts() -> None:
    s = WorldServer(port=0, ms_per_tick=10, timing=FAST)
    port = s.start()
    c = MalmoClient("127.0.0.1", port, synchronous=True, max_backoff=0.2)
    c.init(mission_xml(width=None, height=None, flat="3;7,2*3,2;1;"))
    c.reset()
    c.step("move 1")
    s.stop()
    with pytest.raises((OSError, ConnectionError)):
        for _ in range(3):
            c.step("move 1")
    s2 = WorldServer(port=port, ms_per_tick=10, timing=FAST)
    s2.start()
    try:
        c.reset()
        assert c.step("").info["TotalTime"] == 1
        assert c.reconnects >= 1
    finally:
        c.close()
        s2.stop()
