"""Malmo's real-time semantics: the world ticks on its own, commands take effect at a
later tick, only the latest observation is delivered (once), rewards add up until
collected; and MineRL's synchronous mode advances exactly one tick per step.

Tests named ``..._ideal`` pin the tick-exact rules on an ideal-timing server (one frame
per tick): with real frame pacing a step's reply may show a tick before or after its
own commands ran, so only the real-mode versions' looser rules can be asserted there."""

from __future__ import annotations

import time

import pytest

from actors.tick_meter import TickMeter
from minecraft.malmo.client import MalmoClient
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import IDEAL
from tests.minecraft.conftest import flat_mission

# Real timing: ticks and frames paced by the clock.
pytestmark = pytest.mark.serial

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


def test_commands_apply_at_the_next_tick_ideal() -> None:
    with WorldServer(port=0, seed=7, timing=IDEAL) as server:
        _next_tick_rule(server)


def _next_tick_rule(server: WorldServer) -> None:
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


def test_commands_apply_at_a_later_tick(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=30)
    first = c.observe()
    assert first.info["Yaw"] == 0.0
    r1 = c.step("setYaw 90")
    assert r1.sent
    r2 = c.observe()
    assert r2.info["Yaw"] == 90.0 and r2.info["TotalTime"] > first.info["TotalTime"]
    c.close()


def test_only_latest_observation_and_rewards_summed_ideal() -> None:
    with WorldServer(port=0, seed=7, timing=IDEAL) as server:
        _latest_only_rule(server)


def _latest_only_rule(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=10, rewards=TOUCH_GRASS)
    r0 = c.step("")
    time.sleep(0.25)
    r1 = c.step("")
    skipped = r1.info["TotalTime"] - r0.info["TotalTime"]
    assert skipped >= 5  # intermediate observations were dropped, not queued
    # One reward per tick of standing on grass, all collected by this step.
    assert r1.reward == skipped
    c.close()


def test_latest_observation_once_and_every_reward_collected(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=10, rewards=TOUCH_GRASS, time_limit_ms=1500)
    r = c.observe()
    total, times = r.reward, [r.info["TotalTime"]]
    time.sleep(0.25)
    while not r.done:
        r = c.step("")
        total += r.reward
        if r.info:
            times.append(r.info["TotalTime"])
    assert times[1] - times[0] >= 5  # observations of the sleep were dropped, not queued
    assert all(b > a for a, b in zip(times, times[1:], strict=False))  # each delivered once
    assert total == 30  # one reward per tick on grass, all 30 ticks' collected
    c.close()


def test_fast_steps_wait_for_a_new_tick_ideal() -> None:
    with WorldServer(port=0, seed=7, timing=IDEAL) as server:
        c = _async_client(server, ms_per_tick=15)
        times = [c.step("").info["TotalTime"] for _ in range(8)]
        assert all(b > a for a, b in zip(times, times[1:], strict=False))
        c.close()


def test_fast_steps_are_paced_by_frames_and_may_bring_no_info(server: WorldServer) -> None:
    c = _async_client(server, ms_per_tick=100)  # 10 ticks/s, frames at 60 fps
    replies = [c.step("") for _ in range(12)]
    assert all(r.sent and r.frame.size for r in replies)
    assert sum(not r.info for r in replies) >= 1  # more frames than ticks: empty infos
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
        r = c.step("")
        if r.info:  # frames come faster than ticks: some steps bring no observation
            fast.step(0, r.info["TotalTime"], time.perf_counter() - t0)
    for _ in range(5):
        time.sleep(0.05)  # "training inside the acting loop"
        slow.step(0, c.step("").info["TotalTime"], 0.05)
    assert fast.skipped_fraction() < 0.5 < slow.skipped_fraction()
    assert fast.metrics()["perf/step_latency_ms_p50"] < 1000
    c.close()


def test_a_new_mission_keeps_none_of_the_previous_tick_deadline() -> None:
    # Ideal timing replaces the running mission at once; its next tick was 4.5 s away.
    with WorldServer(port=0, seed=7, timing=IDEAL) as server:
        slow = _async_client(server, ms_per_tick=4500)
        fast = MalmoClient("127.0.0.1", server.port, timeout=10, step_timeout=2.0)
        fast.init(flat_mission(ms_per_tick=10))
        fast.reset()
        first = fast.step("")
        # The next step waits for the next tick: 10 ms after the new mission started, not
        # at the old mission's 4.5 s deadline (the bound is 200 of its ticks).
        assert fast.step("").info["TotalTime"] > first.info["TotalTime"]
        fast.close()
        slow.close()
