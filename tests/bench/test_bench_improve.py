"""bench/improve.py: the table's figures on hand-made seeds, and a --quick run of one task
through the documented commands (graft train, graft eval; local Ray, replay server)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import ray

from bench import improve


def _row(seed: int, tree: float, final: float, evaluations: list[float]) -> improve.SeedRow:
    return improve.SeedRow(
        seed=seed,
        tree=tree,
        final=final,
        tree_in_run=100.0,
        steps=[0, 1000, 2000, 3000][: len(evaluations)],
        evaluations=evaluations,
        env_steps=3000,
        wall_s=10.0,
    )


def test_worst_drop_ignores_the_first_tenth_of_the_budget_and_is_relative_to_the_tree():
    row = _row(0, 100.0, 120.0, [-500.0, 95.0, 130.0, 80.0])  # in-run tree score 100
    # At 0 env steps (within the first tenth of 10,000): not held. Worst after: 80.
    assert improve.worst_drop(row, budget=10_000) == pytest.approx(-0.2)
    assert math.isnan(improve.worst_drop(_row(0, 1.0, 1.0, [5.0]), budget=10_000))


def test_summary_pairs_each_seed_with_the_tree_on_the_same_episodes():
    rows = [
        _row(0, 100.0, 130.0, [100.0, 110.0]),
        _row(1, 90.0, 100.0, [100.0, 105.0]),
        _row(2, 110.0, 105.0, [100.0, 95.0]),
    ]
    s = improve.summarise("t", rows, budget=2000, algorithm="backbone_td3")
    assert s["tree"] == pytest.approx(100.0) and s["final_mean"] == pytest.approx(335 / 3)
    assert s["improvement"] == pytest.approx((30.0 + 10.0 - 5.0) / 3)  # paired, not pooled
    assert s["seeds_at_least_tree"] == 2 and not s["every_seed_at_least_tree"]
    low, high = s["improvement_ci"]
    assert -5.0 <= low < s["improvement"] < high <= 30.0  # the bootstrap of the 3 gains
    assert s["worst_in_run"] == pytest.approx(-0.05) and s["never_far_below"]
    line = improve.table([s]).splitlines()[-1]
    assert line.startswith("| t | backbone_td3 | 3,000 | 100.0 | 130.0, 100.0, 105.0 | +11.7 [")
    assert line.endswith("| 2/3 | -5 % | - | 10 |")  # runs without a selection: no guard


def test_the_guarded_column_is_what_runs_stopped_at_each_evaluation_would_play():
    rows = [_row(0, 100.0, 130.0, [100.0, 50.0]), _row(1, 90.0, 100.0, [100.0, 105.0])]
    rows[0] = dataclasses.replace(rows[0], guarded=[100.0, 100.0])  # the tree kept at 1,000
    rows[1] = dataclasses.replace(rows[1], guarded=[100.0, 105.0])
    s = improve.summarise("t", rows, budget=2000, algorithm="backbone_td3")
    assert s["worst_in_run"] == pytest.approx(-0.5) and not s["never_far_below"]
    assert s["worst_in_run_guarded"] == pytest.approx(0.0) and s["guarded_never_far_below"]
    assert improve.table([s]).splitlines()[-1].endswith("| 2/2 | -50 % | +0 % | 10 |")


def test_fewer_than_three_seeds_get_no_interval_and_no_ci_target():
    s = improve.summarise("t", [_row(0, 1.0, 2.0, [1.0])], budget=10, algorithm="td3")
    assert not s["ci_above_zero"] and all(np.isnan(s["improvement_ci"]))
    assert "(no CI below 3 seeds)" in improve.table([s])


@pytest.mark.slow
@pytest.mark.service
@pytest.mark.timeout(600)
def test_quick_run_of_one_task_trains_scores_and_plots(ray_local, tmp_path, capsys, monkeypatch):
    # Its `graft train` joins the session's cluster, as on a user's (RAY_ADDRESS).
    monkeypatch.setenv("RAY_ADDRESS", ray.get_runtime_context().gcs_address)
    (summary,) = improve.main(["--task", "pendulum", "--quick", "--out", str(tmp_path)])
    assert summary["task"] == "pendulum" and summary["algorithm"] == "backbone_td3"
    assert summary["seeds"] == 1 and np.isfinite(summary["final_mean"])
    assert -1000.0 < summary["tree"] < -200.0  # the swing-up tree on --quick's 10 episodes
    saved = json.loads((tmp_path / "improve-pendulum.json").read_text())
    first = saved["seeds"]["pendulum"][0]
    assert first["evaluations"]  # the in-run evaluations were read, each judged by the guard
    assert len(first["guarded"]) == len(first["evaluations"])
    assert (tmp_path / "improve-pendulum.png").stat().st_size > 0
    assert "| pendulum | backbone_td3 |" in capsys.readouterr().out
    # Read back: the selection applied again gives the run's own choice, on the same
    # episodes; each acting part is scored on the final episodes.
    run = tmp_path / "pendulum" / "s0"
    before = json.loads((run / "summary.json").read_text())["selection"]
    improve.main(["--task", "pendulum", "--quick", "--out", str(tmp_path), "--reselect", "--parts"])
    after = json.loads((run / "summary.json").read_text())
    assert after["selection"] == pytest.approx(before) and "reselected" not in after
    out = capsys.readouterr().out
    assert "| task | seed | tree | π everywhere | with switching | selected (final) |" in out
    saved = json.loads((tmp_path / "improve-pendulum.json").read_text())
    assert set(saved["seeds"]["pendulum"][0]["parts"]) == {"switching", "policy"}


def test_plot_redraws_earlier_runs_from_their_json_without_training(tmp_path):
    rows = [_row(0, 100.0, 130.0, [100.0, 50.0]), _row(1, 90.0, 100.0, [100.0, 105.0])]
    rows[0] = dataclasses.replace(rows[0], guarded=[100.0, 100.0])
    summary = improve.summarise("t", rows, budget=2000, algorithm="backbone_td3")
    saved = tmp_path / "improve-t.json"
    saved.write_text(
        json.dumps({"summaries": [summary], "seeds": {"t": [dataclasses.asdict(r) for r in rows]}})
    )
    (back,) = improve.main(["--plot", str(saved), "--out", str(tmp_path / "fig")])
    assert back["task"] == "t" and back["worst_in_run_guarded"] == 0.0
    assert (tmp_path / "fig" / "improve.png").stat().st_size > 0
