"""bench/fleet.py's measurement, on a real local Ray with a few simulated actors: both
broadcasts deliver every version's weights to every actor, and the figures add up."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import ray

_spec = importlib.util.spec_from_file_location(
    "bench_fleet", Path(__file__).resolve().parents[2] / "bench" / "fleet.py"
)
fleet = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fleet)


@pytest.mark.parametrize("broadcast", ["single", "fan-out"])
def test_every_simulated_actor_ends_holding_the_last_version(ray_local, broadcast) -> None:
    weights = {"w": np.arange(1000, dtype=np.float32)}
    make = fleet.single if broadcast == "single" else lambda w: fleet.fan_out(w, fanout=2)
    followers = fleet.start_fleet(2)  # five actors in two processes: 3 + 2 threads
    args = argparse.Namespace(versions=3, interval=0.2, step_ms=20.0, timeout=60.0)
    r = fleet.measure(make(weights), followers, 5, args)
    for follower in followers:
        ray.kill(follower)
    assert r["complete"], r  # every actor holds version 3
    assert r["pairs"] == 15 and 0 <= r["skipped_pairs"] <= 15
    assert np.isfinite(r["to_all_ms"]) and r["publish_ms"] > 0
    # Two processes, one long-poll each (their subscribers share it): with two per relay
    # the broadcaster answers both, no relay is needed.
    assert r["processes"] == 1
