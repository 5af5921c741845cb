"""Malmo's real-time semantics: the world ticks on its own, commands take effect at the
next tick, only the latest observation is delivered, rewards add up until collected;
and MineRL's synchronous mode advances exactly one tick per step."""

from __future__ import annotations

import time

from actors.minecraft.malmo.client import MalmoClient
from actors.minecraft.sim.server import WorldServer
from actors.tick_meter import TickMeter
from tests.actors.minecraft.conftest import flat_mission

TOUCH_GRASS = (
    '<RewardForTouchingBlockType><Block type="grass" reward="1" behaviour="constant"/>'
    "</RewardForTouchingBlockType>"
)


def _async_client(server: WorldServer, **kw: object) -> MalmoClient:
    c = MalmoClient("127.0.0.1", server.port, synchronous=False, timeout=10)
    c.init(flat_mission(**kw))  # type: ignore[arg-type]
    c.reset()
    return c


def test_world_ticks_without_the_agent(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=10)
    t0 = server.status()["tick"]
    time.sleep(0.3)
    assert server.status()["tick"] - t0 >= 10  # nominally 30 ticks; slack for a busy CI
    c.close()


def test_commands_apply_at_the_next_tick(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=30)
    first = c.step("")
    r1 = c.step("setYaw 90")
    # The reply carries the observation of the tick before the command ran ...
    assert r1.info["Yaw"] == first.info["Yaw"] == 0.0
    r2 = c.step("")
    # ... and the next tick's observation shows it.
    assert r2.info["Yaw"] == 90.0
    assert r2.info["TotalTime"] > r1.info["TotalTime"]
    c.close()


def test_only_latest_observation_and_rewards_summed(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=10, rewards=TOUCH_GRASS)
    r0 = c.step("")
    time.sleep(0.25)
    r1 = c.step("")
    skipped = r1.info["TotalTime"] - r0.info["TotalTime"]
    assert skipped >= 5  # intermediate observations were dropped, not queued
    # One reward per tick of standing on grass, all collected by this step.
    assert r1.reward == skipped
    c.close()


def test_fast_steps_wait_for_a_new_tick(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=15)
    times = [c.step("").info["TotalTime"] for _ in range(8)]
    assert all(b > a for a, b in zip(times, times[1:], strict=False))
    c.close()


def test_synchronous_mode_advances_exactly_one_tick_per_step(server: WorldServer) -> None:
    c = MalmoClient("127.0.0.1", server.port, synchronous=True)
    c.init(flat_mission(ms_per_tick=1000, rewards=TOUCH_GRASS))
    c.reset()
    ticks = []
    for _ in range(30):
        r = c.step("")
        ticks.append(r.info["TotalTime"])
        assert r.reward == 1.0
    assert ticks == list(range(1, 31))
    time.sleep(0.1)
    assert server.status()["tick"] == 30  # no ticking on its own
    c.close()


def test_time_limit_ends_the_mission(sync_client) -> None:
    c = sync_client(time_limit_ms=500)  # 10 ticks of game time
    dones = [c.step("").done for _ in range(10)]
    assert dones == [False] * 9 + [True]


def test_tick_meter_counts_skips_of_a_slow_actor(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=10)
    fast, slow = TickMeter(1), TickMeter(1)
    for _ in range(10):
        t0 = time.perf_counter()
        fast.step(0, c.step("").info["TotalTime"], time.perf_counter() - t0)
    for _ in range(5):
        time.sleep(0.05)  # "training inside the acting loop"
        slow.step(0, c.step("").info["TotalTime"], 0.05)
    assert fast.skipped_fraction() < 0.5 < slow.skipped_fraction()
    assert fast.metrics()["perf/step_latency_ms_p50"] < 1000
    c.close()
