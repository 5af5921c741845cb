"""bench/improve.py: the table's figures on hand-made seeds, and a --quick run of one task
through the documented commands (graft train, graft eval; local Ray, replay server)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import ray

from bench import improve, improve_report
from graft.seeds import evaluation_seed
from learner.checkpoint import find_checkpoint, load_checkpoint


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


@pytest.mark.parametrize("task", sorted(improve.TASKS))
def test_every_task_has_a_from_scratch_arm_on_its_own_preset(task):
    scratch = improve.load_preset(
        improve.TASKS[task], **improve.parse_settings(list(improve.SCRATCH[task]))
    )
    recipe = improve.load_preset(improve.TASKS[task])
    assert scratch.algorithm in ("td3", "ddqn")
    assert (recipe.env_id, recipe.env_steps) == (scratch.env_id, scratch.env_steps)


def test_scratch_set_adds_to_from_scratchs_settings_and_leaves_the_recipe_alone():
    """`--scratch-set td3.critic_layer_norm=all`: a from-scratch control for a recipe
    candidate, the same change without the tree."""
    given = ["td3.critic_layer_norm=all"]
    settings = improve.arm_overrides("halfcheetah", "scratch", given, quick=False)
    assert settings == [*improve.SCRATCH["halfcheetah"], *given]
    scratch = improve.load_preset(improve.TASKS["halfcheetah"], **improve.parse_settings(settings))
    assert (scratch.algorithm, scratch.td3.critic_layer_norm) == ("td3", "all")
    quick = improve.arm_overrides("halfcheetah", "scratch", ["eval_every=500"], quick=True)
    assert "eval_every=500" in quick and "eval_every=300" not in quick  # the caller's stays
    assert improve.arm_overrides("halfcheetah", "recipe", [], quick=False) == []
    with pytest.raises(SystemExit):
        improve.main(["--task", "halfcheetah", "--scratch-set", "td3.critic_layer_norm"])


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
    assert s["seeds_above_tree"] == 2 and not s["every_seed_above_tree"]
    low, high = s["improvement_ci"]
    assert -5.0 <= low < s["improvement"] < high <= 30.0  # the bootstrap of the 3 gains
    assert s["worst_in_run"] == pytest.approx(-0.05) and s["never_far_below"]
    line = improve.table([s]).splitlines()[-1]
    assert line.startswith(
        "| t | recipe: backbone_td3 | 3,000 | 100.0 | 130.0, 100.0, 105.0 | +11.7 ["
    )
    assert line.endswith("| 2/3 | -5 % | - | 10 |")  # runs without a selection: no guard


def test_a_seed_that_ties_the_tree_is_not_counted_as_improved():
    # The selection kept the tree on seed 1: its final is the tree's score exactly.
    rows = [_row(0, 100.0, 130.0, [100.0]), _row(1, 90.0, 90.0, [100.0])]
    s = improve.summarise("t", rows, budget=2000, algorithm="ddqn")
    assert s["seeds_above_tree"] == 1 and not s["every_seed_above_tree"]
    assert "| 1/2 |" in improve.table([s])


def test_the_guarded_column_is_what_runs_stopped_at_each_evaluation_would_play():
    rows = [_row(0, 100.0, 130.0, [100.0, 50.0]), _row(1, 90.0, 100.0, [100.0, 105.0])]
    rows[0] = dataclasses.replace(rows[0], guarded=[100.0, 100.0])  # the tree kept at 1,000
    rows[1] = dataclasses.replace(rows[1], guarded=[100.0, 105.0])
    s = improve.summarise("t", rows, budget=2000, algorithm="backbone_td3")
    assert s["worst_in_run"] == pytest.approx(-0.5) and not s["never_far_below"]
    # A diagnostic with a floor by construction, never a target.
    assert s["worst_in_run_guarded"] == pytest.approx(0.0) and "guarded_never_far_below" not in s
    assert "guarded (a floor by construction)" in improve.table([s]).splitlines()[0]
    assert improve.table([s]).splitlines()[-1].endswith("| 2/2 | -50 % | +0 % | 10 |")


def test_the_recipes_margin_is_over_the_better_of_the_tree_and_from_scratch_by_seed():
    tree = [100.0, 90.0, 110.0]
    recipe = [_row(s, tree[s], f, [1.0]) for s, f in enumerate([150.0, 140.0, 125.0])]
    scratch = [_row(s, tree[s], f, [1.0]) for s, f in enumerate([160.0, 120.0, 140.0])]
    row = improve_report.compare("t", {"scratch": scratch, "recipe": recipe})
    assert row["better"] == "scratch" and row["tree"] == pytest.approx(100.0)
    assert row["margin"] == pytest.approx((-10.0 + 20.0 - 15.0) / 3)  # paired by seed
    low, high = row["margin_ci"]
    assert -15.0 <= low <= row["margin"] <= high <= 20.0
    assert row["recipe_seeds_above_tree"] == 3 and not row["margin_met"]
    weak = [_row(s, t, t - 50.0, [1.0]) for s, t in enumerate(tree)]  # below the tree
    row = improve_report.compare("t", {"scratch": weak, "recipe": recipe})
    assert row["better"] == "tree" and row["margin"] == pytest.approx((50 + 50 + 15) / 3)
    line = improve_report.task_table([row]).splitlines()[-1]
    assert line.startswith("| t | 3,000 | 100.0 | 50.0 [") and "vs tree | 3/3 |" in line


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
    given = ["--set", "eval_episodes=2"]  # --quick's own value: recorded, nothing changed
    (task,) = improve.main(["--task", "pendulum", "--quick", *given, "--out", str(tmp_path)])
    assert task["task"] == "pendulum" and task["recipe"]["seeds"] == task["scratch"]["seeds"] == [0]
    assert np.isfinite(task["recipe"]["mean"]) and np.isfinite(task["scratch"]["mean"])
    assert -1000.0 < task["tree"] < -200.0  # the swing-up tree on --quick's 10 episodes
    assert np.isfinite(task["margin"])  # one seed: no interval
    saved = json.loads((tmp_path / "improve-pendulum.json").read_text())
    assert [(s["arm"], s["algorithm"]) for s in saved["summaries"]] == [
        ("scratch", "td3"),
        ("recipe", "backbone_td3"),
    ]
    assert saved["commit"] and saved["settings"] == {"set": ["eval_episodes=2"], "scratch_set": []}
    first = saved["seeds"]["pendulum"]["recipe"][0]
    assert first["evaluations"]  # the in-run evaluations were read, each judged by the guard
    assert len(first["guarded"]) == len(first["evaluations"])
    assert (tmp_path / "improve-pendulum.png").stat().st_size > 0
    assert "| pendulum | recipe: backbone_td3 |" in capsys.readouterr().out
    # Read back: the selection applied again gives the run's own choice, on the same
    # episodes; each acting part is scored on the final episodes.
    run = tmp_path / "pendulum" / "recipe" / "s0"
    before = json.loads((run / "summary.json").read_text())["selection"]
    improve.main(
        ["--task", "pendulum", "--quick", "--out", str(tmp_path), "--reselect", "--parts"]
        + ["--arm", "recipe"]
    )
    after = json.loads((run / "summary.json").read_text())
    assert after["selection"] == pytest.approx(before) and "reselected" not in after
    assert after["evaluation_seed"] == evaluation_seed(0)
    out = capsys.readouterr().out
    assert "| task | seed | tree | π everywhere | with switching | selected (final) |" in out
    saved = json.loads((tmp_path / "improve-pendulum.json").read_text())
    assert set(saved["seeds"]["pendulum"]["recipe"][0]["parts"]) == {"switching", "policy"}
    # A new rule: the run's summary and its last checkpoint take its choice, and say how;
    # one no policy passes (z = 1000) keeps the tree, and the final is scored as the tree.
    stricter = ["--set", "selection.episodes=3", "--set", "selection.z=1000"]
    improve.main(
        ["--task", "pendulum", "--quick", "--out", str(tmp_path), "--reselect", "--arm", "recipe"]
        + stricter
    )
    after = json.loads((run / "summary.json").read_text())
    assert after["reselected"] == {"episodes": 3, "z": 1000.0, "seed": evaluation_seed(0)}
    assert after["selection"]["tree_kept"] == 1.0
    checkpoint, _ = find_checkpoint(run)
    assert load_checkpoint(checkpoint)["algorithm"]["tree_only"] is True
    row = json.loads((tmp_path / "improve-pendulum.json").read_text())["seeds"]["pendulum"]
    assert row["recipe"][0]["final"] == pytest.approx(row["recipe"][0]["tree"])


def test_plot_redraws_earlier_runs_from_their_json_without_training(tmp_path):
    rows = [_row(0, 100.0, 130.0, [100.0, 50.0]), _row(1, 90.0, 100.0, [100.0, 105.0])]
    rows[0] = dataclasses.replace(rows[0], guarded=[100.0, 100.0])
    summary = improve.summarise("t", rows, budget=2000, algorithm="backbone_td3")
    saved = tmp_path / "improve-t.json"
    saved.write_text(
        json.dumps({"summaries": [summary], "seeds": {"t": [dataclasses.asdict(r) for r in rows]}})
    )
    (back,) = improve.main(["--plot", str(saved), "--out", str(tmp_path / "fig")])
    assert back["task"] == "t" and back["recipe"]["seeds"] == [0, 1]  # an older file: the recipe
    redrawn = json.loads((tmp_path / "fig" / "improve.json").read_text())
    assert redrawn["summaries"][0]["worst_in_run_guarded"] == 0.0
    assert redrawn["commit"] == "unrecorded"  # the runs' commit, carried over from their files
    assert (tmp_path / "fig" / "improve-t.png").stat().st_size > 0


def _saved(path, task, rows, env_steps, arm="recipe"):
    rows = [dataclasses.replace(r, env_steps=env_steps) for r in rows]
    summary = improve.summarise(task, rows, budget=env_steps, algorithm="backbone_td3")
    data = {
        "summaries": [{**summary, "arm": arm}],
        "seeds": {task: {arm: [dataclasses.asdict(r) for r in rows]}},
    }
    path.write_text(json.dumps(data))
    return path


def test_a_run_s_budget_is_its_env_steps_rounded_down_to_two_digits():
    assert [improve.budget_of(n) for n in (30_648, 50_176, 10_016, 100_000, 600)] == [
        30_000,
        50_000,
        10_000,
        100_000,
        600,
    ]


def test_plot_gives_a_task_a_row_per_budget_and_takes_a_seed_in_two_files_from_the_later(
    tmp_path, capsys
):
    short = [_row(s, 100.0, 150.0 + s, [100.0]) for s in range(3)]
    long = [_row(s, 100.0, 300.0 + s, [100.0]) for s in range(3)]
    rescored = [dataclasses.replace(long[2], final=250.0)]  # seed 2 again, scored anew
    files = [
        _saved(tmp_path / "a.json", "t", short, 30_648),
        _saved(tmp_path / "b.json", "t", long, 100_000),
        _saved(tmp_path / "c.json", "t", long[:1], 100_000),  # seed 0 again, the same row
        _saved(tmp_path / "d.json", "t", rescored, 100_000),
    ]
    rows = improve.main(["--plot", *map(str, files), "--out", str(tmp_path / "fig")])
    by_name = {r["task"]: r for r in rows}
    assert sorted(by_name) == ["t-100k", "t-30k"]
    assert by_name["t-30k"]["recipe"]["mean"] == pytest.approx(151.0)
    assert by_name["t-100k"]["recipe"]["seeds"] == [0, 1, 2]  # seed 0 once
    assert by_name["t-100k"]["recipe"]["mean"] == pytest.approx((300.0 + 301.0 + 250.0) / 3)
    said = capsys.readouterr().out
    assert f"{files[3]}'s (250.0) replaces {files[1]}'s (302.0)" in said
    assert str(files[2]) not in said  # an identical seed is not a replacement
    assert (tmp_path / "fig" / "improve-t-30k.png").stat().st_size > 0


def test_plot_keeps_a_probe_run_with_sets_beside_the_arm_not_pooled_into_it(tmp_path):
    plain = [_row(s, 100.0, 150.0, [100.0]) for s in range(3)]
    probe = [_row(s, 100.0, 400.0, [100.0]) for s in range(3)]
    files = [
        _saved(tmp_path / f"{n}.json", "t", rows, 30_000)
        for n, rows in (("a", plain), ("b", probe))
    ]
    data = json.loads(files[1].read_text())
    settings = {"set": ["td3.tau=0.01"], "scratch_set": []}
    files[1].write_text(json.dumps({**data, "settings": settings}))
    (row,) = improve.main(["--plot", *map(str, files), "--out", str(tmp_path / "fig")])
    assert row["recipe"]["mean"] == pytest.approx(150.0)  # the plain recipe's seeds alone
    redrawn = json.loads((tmp_path / "fig" / "improve.json").read_text())
    assert sorted(redrawn["seeds"]["t"]) == ["recipe", "recipe [td3.tau=0.01]"]
    assert improve.probe_name("scratch", {"set": ["a=1"], "scratch_set": []}) == "scratch"
    assert improve.probe_name("sb3-sac", {"set": ["a=1"]}) == "sb3-sac"


def test_along_the_budget_pairs_each_seeds_in_run_evaluations_at_the_same_env_steps():
    recipe = [
        dataclasses.replace(
            _row(s, 100.0, 0.0, [150.0, 160.0, 170.0 + s]), steps=[3008, 10016, 20000]
        )
        for s in range(3)
    ]
    scratch = [
        dataclasses.replace(_row(s, 100.0, 0.0, [0.0, 180.0 - s]), steps=[9984, 20000])
        for s in range(3)
    ]
    points = improve_report.along_budget({"recipe": recipe, "scratch": scratch})
    assert [p["env_steps"] for p in points] == [10_000, 20_000]  # 3,008: from scratch had none
    assert points[0]["lead"] == pytest.approx(160.0) and points[0]["lead_ci"][0] > 0
    assert points[1]["lead"] == pytest.approx(np.mean([-10.0 + 2 * s for s in range(3)]))
    assert improve_report.along_budget({"recipe": recipe}) == []
    table = improve_report.along_budget_table({"t": points})
    assert "| t | 20,000 | 179.0 | 171.0 | -8.0 [" in table
