"""bench/soak.py: its slope verdict on hand-made series, and a 2-minute soak of a real
pendulum-td3 run (an env actor killed every 40 s, the replay server once) that must
survive to a clean stop with every series sampled."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "bench_soak", Path(__file__).resolve().parents[2] / "bench" / "soak.py"
)
soak = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(soak)


def _rows(metric: str, per_minute: float, minutes: int = 30) -> list:
    # A warm-up jump in the first tenth, which the verdict must leave out.
    warm = [(0.0, "learner", metric, 0.0), (1.0, "learner", metric, 500.0)]
    return warm + [(float(m), "learner", metric, 500.0 + per_minute * m) for m in range(3, minutes)]


@pytest.mark.parametrize(
    ("metric", "per_minute", "ok"),
    [("rss_mib", 0.0, True), ("rss_mib", 1.0, True), ("rss_mib", 1.2, False),
     ("fds", 0.4, True), ("fds", 1.0, False), ("run_dir_mib", 4.0, True)],
)  # fmt: skip
def test_a_series_fails_only_when_it_grows_past_its_limit(metric, per_minute, ok) -> None:
    (verdict,) = soak.slopes(_rows(metric, per_minute))
    assert verdict["slope_per_h"] == pytest.approx(per_minute * 60, abs=1e-6)
    assert verdict["ok"] is ok


def test_growth_that_levels_off_in_the_first_half_passes_and_growth_that_goes_on_fails() -> None:
    # A capped history: 5 MiB a minute for 12 minutes, then flat (Ray's GCS with its cap).
    capped = [(float(m), "ray gcs", "rss_mib", 50.0 + 5.0 * min(m, 12)) for m in range(31)]
    (verdict,) = soak.slopes(capped)
    assert verdict["slope_per_h"] > 64 and verdict["late_slope_per_h"] == pytest.approx(0.0)
    assert verdict["ok"]
    # The same rise kept up past half way is a leak.
    leak = [(float(m), "ray gcs", "rss_mib", 50.0 + 2.0 * m) for m in range(31)]
    (verdict,) = soak.slopes(leak)
    assert verdict["late_slope_per_h"] == pytest.approx(120.0) and not verdict["ok"]


@pytest.mark.long
@pytest.mark.service
@pytest.mark.serial
def test_a_two_minute_soak_survives_its_faults_and_samples_every_series(tmp_path) -> None:
    out = tmp_path / "soak"
    status = soak.main(
        ["--minutes", "2", "--sample-every-s", "15", "--kill-every-s", "40", "--out", str(out)]
    )
    report = json.loads((out / "soak.json").read_text())
    events = report["events"]
    assert events["returncode"] == 143, events  # stopped by SIGTERM as Ctrl-C would
    assert events["replay_kills"] == 1 and events["actor_kills"] >= 2, events
    assert events["env_steps"] > 0 and events["updates"] > 0, events
    with open(out / "soak.csv") as f:
        rows = list(csv.DictReader(f))
    seen = {(r["role"], r["metric"]) for r in rows}
    for role in ("learner", "replay server", "env actors", "evaluator", "ray gcs", "ray raylet"):
        for metric in ("rss_mib", "fds", "threads", "processes"):
            assert (role, metric) in seen, (role, metric)
    assert ("ray raylet", "object_store_mib") in seen and ("run folder", "run_dir_mib") in seen
    assert (out / "soak.png").stat().st_size > 0
    # Two minutes are too short for the slopes to mean much; the verdict is still made.
    assert status == (0 if all(v["ok"] for v in report["slopes"]) else 1)
