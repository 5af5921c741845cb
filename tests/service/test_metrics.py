"""Run metrics: the policy-lag meter on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from service.metrics import (
    MetricsLogger,
    PolicyLag,
    plot_learning_curve,
    read_evaluations,
    read_metric,
)


def test_policy_lag_counts_versions_published_before_each_item_was_acted() -> None:
    lag = PolicyLag()
    for version, wall in [(0, 10.0), (1, 20.0), (2, 30.0)]:
        lag.published(version, wall)
    batch = {
        # acted with:     v0 at 15  v0 at 25  v0 at 35  v2 at 31  warm-up  v1 stamped 1 ms early
        "policy_version": np.array([0, 0, 0, 2, -1, 1]),
        "acted_at": np.array([15.0, 25.0, 35.0, 31.0, 5.0, 19.999]),
    }
    metrics = lag.measure(batch, version=3, now=40.0)
    # Newest version at each acting time: 0, 1, 2, 2, (left out), 0 -> lags 0, 1, 2, 0, 0
    # (clock skew never makes a lag negative).
    assert metrics["perf/policy_lag"] == pytest.approx(3 / 5)
    assert metrics["perf/policy_lag_max"] == 2
    assert metrics["perf/policy_lag_p90"] == pytest.approx(1.6)  # of [0, 0, 0, 1, 2]
    assert metrics["perf/sample_age_versions"] == pytest.approx((3 + 3 + 3 + 1 + 2) / 5)
    assert metrics["perf/sample_age_s"] == pytest.approx((25 + 15 + 5 + 9 + 20.001) / 5)


@pytest.mark.parametrize(
    "batch",
    [
        {"policy_version": np.array([-1, -1]), "acted_at": np.array([1.0, 2.0])},  # warm-up only
        {"policy_version": np.array([0, 0])},  # written without acting times
    ],
)
def test_policy_lag_is_left_out_when_no_item_can_show_it(batch) -> None:
    lag = PolicyLag()
    lag.published(0, 0.0)
    assert lag.measure(batch, version=0, now=5.0) == {}


@pytest.mark.parametrize(
    "left",
    [b"", b"wall_s,env_steps,updates,key,value\n1.0,10,1,losses/critic,0.5\n1.0,1"],
    ids=["header-never-flushed", "torn-last-row"],
)
def test_a_run_resumed_after_a_sigkill_appends_to_a_readable_metrics_csv(tmp_path, left) -> None:
    """A killed run leaves metrics.csv empty or ending mid-row; the resumed run's logger
    writes the header again or cuts the torn row, and the file reads whole."""
    (tmp_path / "metrics.csv").write_bytes(left)
    logger = MetricsLogger(tmp_path)
    logger.log({"losses/critic": 0.25}, env_steps=20, updates=2)
    logger.close()
    steps, values = read_metric(tmp_path / "metrics.csv", "losses/critic")
    assert steps == ([10, 20] if left else [20]) and values == ([0.5, 0.25] if left else [0.25])


def test_an_evaluation_cut_between_its_rows_is_left_out_of_the_curve(tmp_path) -> None:
    """A run stopped (Ctrl-C, SIGTERM) between an evaluation's mean and std rows, then
    resumed: the curve pairs each mean with its own std and draws; the lone mean is left out."""
    logger = MetricsLogger(tmp_path)
    logger.log({"eval/return_mean": -5.0, "eval/return_std": 1.0}, env_steps=100, updates=10)
    logger.log({"eval/return_mean": -4.0}, env_steps=200, updates=20)
    logger.log({"eval/return_mean": -3.0, "eval/return_std": 0.5}, env_steps=300, updates=30)
    logger.close()
    assert read_evaluations(tmp_path / "metrics.csv") == [(100, -5.0, 1.0), (300, -3.0, 0.5)]
    plot_learning_curve(tmp_path / "metrics.csv", tmp_path / "curve.png", title="t")
    assert (tmp_path / "curve.png").stat().st_size > 0
