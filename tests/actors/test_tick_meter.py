"""TickMeter on hand-made clocks: gaps between observations are skipped ticks, episodes
and environments are counted apart, latencies give percentiles."""

from __future__ import annotations

import math

import pytest

from actors.tick_meter import TickMeter


@pytest.mark.parametrize(
    "ticks, skipped",
    [
        ([5, 6, 7, 8], [0, 0, 0]),  # every tick seen
        ([5, 6, 8, 12], [0, 1, 3]),  # gaps of 2 and 4: 1 and 3 ticks unseen
        ([5, 5, 6], [0, 0]),  # no new tick (an observation repeated): nothing skipped
    ],
)
def test_gaps_are_skipped_ticks(ticks: list[int], skipped: list[int]) -> None:
    meter = TickMeter(1)
    meter.begin(0, ticks[0])
    assert [meter.step(0, t, 0.001) for t in ticks[1:]] == skipped
    m = meter.metrics()
    assert m["perf/ticks_seen"] == len(ticks)
    assert m["perf/ticks_skipped"] == sum(skipped)
    assert m["perf/ticks_skipped_fraction"] == pytest.approx(
        sum(skipped) / (len(ticks) + sum(skipped))
    )


def test_episodes_and_environments_have_their_own_clocks() -> None:
    meter = TickMeter(2)
    meter.begin(0, 10)
    meter.begin(1, 500)
    assert meter.step(0, 12, 0.0) == 1
    assert meter.step(1, 501, 0.0) == 0  # env 1's clock, not env 0's
    meter.begin(0, 3)  # a new episode: the clock restarts, no gap counted
    assert meter.step(0, 4, 0.0) == 0
    assert (meter.seen, meter.skipped) == (6, 1)  # 6 observations, 1 tick unseen


def test_restart_clears_the_window_but_keeps_the_clocks() -> None:
    meter = TickMeter(1)
    meter.begin(0, 1)
    meter.step(0, 5, 0.010)
    meter.restart()
    assert meter.step(0, 7, 0.002) == 1  # the gap from tick 5 still counts
    m = meter.metrics()
    assert (m["perf/ticks_seen"], m["perf/ticks_skipped"]) == (1, 1)
    assert m["perf/step_latency_ms_p50"] == pytest.approx(2.0)


def test_latency_percentiles_and_no_ticks_reported() -> None:
    meter = TickMeter(1)
    assert math.isnan(meter.metrics()["perf/step_latency_ms_p50"])
    meter.begin(0, None)
    for latency in (0.001, 0.002, 0.003, 0.004, 0.100):
        meter.step(0, None, latency)
    m = meter.metrics()
    assert m["perf/step_latency_ms_p50"] == pytest.approx(3.0)
    assert m["perf/step_latency_ms_p99"] == pytest.approx(4.0 + 0.96 * 96.0)
    assert "perf/ticks_seen" not in m  # an environment without a clock has no tick counts
