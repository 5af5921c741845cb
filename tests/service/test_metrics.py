"""Run metrics: the policy-lag meter on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest

from service.metrics import MetricsLogger, PolicyLag, read_metric


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
