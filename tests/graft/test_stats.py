"""Per-seed statistics: IQM as rliable/scipy cut it, bootstrap intervals that cover the
mean, and no interval from fewer than three seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from graft.experiments.runner import summarise
from graft.experiments.stats import bootstrap_ci, iqm, main, summarize


@pytest.mark.parametrize(
    "values, expected",
    [
        ([1.0, 2.0, 3.0], 2.0),  # n < 4: nothing cut, the mean
        ([1.0, 2.0, 3.0, 100.0], 2.5),  # one value cut at each end
        ([0.0, 10.0, 1.0, 2.0, 3.0, -50.0, 4.0, 5.0], 2.5),  # two cut at each end: 1..4
    ],
)
def test_iqm_is_the_mean_of_the_middle_half(values, expected):
    assert iqm(values) == expected


def test_the_interval_contains_the_mean_and_narrows_with_more_seeds():
    rng = np.random.default_rng(1)
    few, many = rng.normal(0, 1, 5), rng.normal(0, 1, 100)
    for values in (few, many):
        low, high = bootstrap_ci(values, np.mean)
        assert low < values.mean() < high
    assert np.ptp(bootstrap_ci(many, np.mean)) < np.ptp(bootstrap_ci(few, np.mean))
    # Seeded: the same values give the same interval.
    assert bootstrap_ci(few, np.mean) == bootstrap_ci(few, np.mean)


def test_fewer_than_three_seeds_get_no_interval(capsys):
    two = summarize([-137.0, -136.0])
    assert all(math.isnan(v) for v in (*two.mean_ci, *two.iqm_ci))
    assert two.line() == "mean -136.5 (2 seeds: -137.0, -136.0; no interval)"
    assert summarize([-155.1]).line() == "mean -155.1 (1 seed, no interval)"
    main(["--", "-132.8", "-136.9", "-135.9", "-135.2", "-134.8"])
    out = capsys.readouterr().out
    assert out.startswith("mean -135.1 [") and "5 seeds (95 % bootstrap CI)" in out


def test_non_finite_values_are_refused():
    with pytest.raises(ValueError, match="finite per-seed values"):
        summarize([1.0, float("nan")])


def test_an_experiment_summary_gives_an_interval_from_three_seeds_on():
    finals = {"a": [-140.0, -150.0, -130.0], "b": [-300.0, -100.0]}
    rows = [
        {"variant": v, "seed": str(seed), "env_steps": str(steps), "return_mean": str(value)}
        for v, values in finals.items()
        for seed, last in enumerate(values)
        for steps, value in ((1000, -1000.0), (2000, last))
    ]
    a, b = summarise(rows, ["a", "b"])
    assert (a["seeds"], a["final_mean"], a["final_iqm"]) == (3, -140.0, -140.0)
    assert a["final_ci95_low"] < -140.0 < a["final_ci95_high"]
    assert (b["seeds"], b["final_mean"], b["final_ci95_low"], b["final_iqm"]) == (
        2,
        -200.0,
        None,
        None,
    )
