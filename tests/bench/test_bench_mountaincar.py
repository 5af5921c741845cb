"""bench/mountaincar.py: the table's columns on hand-made episodes, and a --quick run of the
whole benchmark through the real service (local Ray, replay server, learner)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

_spec = importlib.util.spec_from_file_location(
    "bench_mountaincar", Path(__file__).resolve().parents[2] / "bench" / "mountaincar.py"
)
mountaincar = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mountaincar)


def _final(returns: list[float], reached: list[float]) -> dict[str, np.ndarray]:
    return {"returns": np.array(returns), "reached": np.array(reached)}


def test_summary_counts_seeds_episodes_and_first_evaluations() -> None:
    finals = [_final([90.0, 92.0], [1.0, 1.0]), _final([90.0, -10.0], [1.0, 0.0])]
    runs = [{"reached": [1.0, 1.0]}, {"reached": [0.5, 1.0]}]
    row = mountaincar.summarise("m", finals, runs)
    assert row["seeds_always_reaching"] == 1  # the second seed missed one final episode
    assert row["success_rate"] == pytest.approx(0.75)  # 3 of 4 episodes
    assert row["return_mean"] == pytest.approx((91.0 + 40.0) / 2)  # mean of seed means
    assert row["return_std_over_seeds"] == pytest.approx(25.5)
    assert row["seeds_reaching_from_first_eval"] == 1  # seed 1's first evaluation: 1 of 2
    assert (
        mountaincar.summarise("tree", finals, [None, None])["seeds_reaching_from_first_eval"]
        is None
    )


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_quick_benchmark_runs_every_method_and_writes_its_plot(ray_local, tmp_path, capsys) -> None:
    # One run at a time: one Ray task worker imports torch once and hands its run's helpers
    # (broadcaster, evaluator, actors) from method to method.
    rows = mountaincar.main(["--quick", "--parallel", "1", "--out", str(tmp_path)])
    methods = ["tree alone", "plain TD3", "backbone TD3", "backbone TD3, correction within ±0.7"]
    assert [r["method"] for r in rows] == methods
    assert all(r["seeds"] == 1 and np.isfinite(r["return_mean"]) for r in rows)
    tree = rows[0]
    assert tree["success_rate"] == 1.0 and tree["return_mean"] > 85.0  # the tree always arrives
    out = capsys.readouterr().out
    assert "| tree alone | 1/1 | 100% |" in out
    assert (tmp_path / "mountaincar.png").stat().st_size > 0
