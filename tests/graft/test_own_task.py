"""A user's own task, in a package graft never imports (tests/fixtures/usertask, installed
as its own distribution), through every method by `graft.train(...)`, and by `graft train
--preset path/to/task.yaml` in a fresh process; each run then loaded back by `graft eval`.

Real parts throughout: a local Ray cluster, the replay server process, the learner.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import ray
import yaml

import graft
from graft.cli import main

REPO = Path(__file__).resolve().parents[2]
PRESETS = REPO / "tests" / "fixtures" / "usertask" / "presets"

METHODS = {
    # method: (preset file, overrides)
    "td3": ("reach.yaml", {"algorithm": "td3"}),
    "backbone_td3": ("reach.yaml", {}),  # μ: the user's py_trees tree
    # Dict observations through the preset's wrapper; μ a function beside the YAML.
    "pretrain_td3": ("reach-dict.yaml", {}),
    # The hard-coded option: a batched function of the user's package.
    "options": (
        "reach.yaml",
        {"algorithm": "options", "hardcoded_policy": "usertask.policies:batched_reach"},
    ),
    "ddqn": ("reach-discrete.yaml", {}),  # discrete actions
}
# 200 online env steps past learning_starts=100, one update each; pretrain_td3: 20
# pre-training updates on its 100 demonstrations, 100 online and a burn-in of 10.
UPDATES = {"td3": 200, "backbone_td3": 200, "pretrain_td3": 130, "options": 200, "ddqn": 200}
ENV_IDS = {
    "reach.yaml": "usertask.envs:Reach1D-v0",
    "reach-dict.yaml": "usertask.envs:DictReach",
    "reach-discrete.yaml": "usertask.envs:DiscreteReach",
}


def _check_run(run_dir: Path, method: str) -> dict:
    """The run folder holds what a user needs: summary, checkpoint, the resolved config."""
    summary = json.loads((run_dir / "summary.json").read_text())
    assert 300 - 16 <= summary["env_steps"] <= 300, summary  # the budget, within slack
    assert summary["updates"] == UPDATES[method], summary
    assert np.isfinite(summary["final_eval_return_mean"])
    assert list((run_dir / "checkpoints").glob("ckpt-*.pt"))
    recorded = yaml.safe_load((run_dir / "config.yaml").read_text())
    preset, _ = METHODS[method]
    assert recorded["algorithm"] == method and recorded["env_id"] == ENV_IDS[preset]
    assert str(PRESETS) in recorded["import_path"]  # the preset's folder, recorded
    versions = recorded["versions"]
    assert versions["graft-rl"] and versions["torch"]
    assert versions["task"]["usertask"] == "usertask 0.3.1"  # the user's distribution
    # The environment's own episode metric is logged beside the return.
    with (run_dir / "metrics.csv").open() as f:
        reached = [float(row["value"]) for row in csv.DictReader(f) if row["key"] == "eval/reached"]
    assert reached and all(0.0 <= r <= 1.0 for r in reached)
    return recorded


def _eval_json(run_dir: Path, capsys: pytest.CaptureFixture[str]) -> dict:
    main(["eval", "--policy", str(run_dir), "--episodes", "2", "--json"])
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("method", sorted(set(METHODS) - {"td3"}))  # td3: the teacher test
def test_graft_train_runs_every_method_on_the_users_task(
    method: str, ray_local, tmp_path, monkeypatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)  # neither the preset's folder nor graft's
    preset, overrides = METHODS[method]
    run = graft.train(PRESETS / preset, run_dir=tmp_path / "run", **overrides)
    assert run.config.algorithm == method
    _check_run(run.run_dir, method)
    result = _eval_json(run.run_dir, capsys)
    assert result["env_id"] == ENV_IDS[preset] and np.isfinite(result["mean"])
    # The Python API loads the same policy: one observation in, one action out.
    policy = graft.load_policy(run.run_dir)
    obs, _ = policy.make_env().reset(seed=0)
    action = policy(obs)
    assert action.shape == (() if method == "ddqn" else (1,))


def _graft(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """The `graft` command in a fresh process, from `cwd`."""
    path = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    return subprocess.run(
        [sys.executable, "-m", "graft.cli", *args],
        cwd=cwd,
        env={**os.environ, "PYTHONPATH": path},
        capture_output=True,
        text=True,
        timeout=240,
    )


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_graft_train_preset_path_in_a_subprocess(ray_local, tmp_path) -> None:
    """`graft train --preset path --set ...` and `graft eval` each in a fresh process, from
    folders that are neither graft's nor the preset's: the run's recorded import path finds
    the policy module kept beside the preset (reach-dict.yaml's μ). Every method's own path
    through the same `train` is test_graft_train_runs_every_method_on_the_users_task's."""
    method = "pretrain_td3"
    preset, _ = METHODS[method]
    address = ray.get_runtime_context().gcs_address  # join the session's cluster
    run_dir = tmp_path / "runs" / method
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    train = _graft(
        ["train", "--preset", str(PRESETS / preset), "--address", address,
         "--run-dir", str(run_dir), "--no-progress", "--set", "seed=3"],
        cwd=elsewhere,
    )  # fmt: skip
    assert train.returncode == 0, train.stderr[-3000:]
    assert f"run folder: {run_dir}" in train.stdout
    assert _check_run(run_dir, method)["seed"] == 3
    evaluated = _graft(["eval", "--policy", str(run_dir), "--episodes", "2", "--json"], tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr[-3000:]
    result = json.loads(evaluated.stdout)
    assert result["env_id"] == ENV_IDS[preset] and 0.0 <= result["reached"] <= 1.0


def test_backbone_teacher_and_resume_load_runs_from_their_folders(
    ray_local, tmp_path, monkeypatch, capsys
) -> None:
    """A TD3 run trained from a user YAML serves as the backbone's teacher, and resumes
    from its own folder with no preset given."""
    monkeypatch.chdir(tmp_path)
    reach = PRESETS / "reach.yaml"
    teacher = graft.train(reach, run_dir=tmp_path / "teacher", algorithm="td3")
    _check_run(teacher.run_dir, "td3")
    student = graft.train(
        reach, run_dir=tmp_path / "student", **{"backbone.teacher": str(teacher.run_dir)}
    )
    assert student.config.backbone.teacher == str(teacher.run_dir)
    assert _eval_json(student.run_dir, capsys)["env_id"] == ENV_IDS["reach.yaml"]
    # `graft train --resume --run-dir RUN` with no --preset: the run's own config.
    main(["train", "--resume", "--run-dir", str(teacher.run_dir), "--env-steps", "500",
          "--no-progress"])  # fmt: skip
    resumed = json.loads((teacher.run_dir / "summary.json").read_text())
    assert resumed["preset"] == "reach" and 400 < resumed["env_steps"] <= 500
    assert resumed["updates"] > teacher.summary["updates"]


@pytest.mark.parametrize("preset", sorted(ENV_IDS))
def test_hardcoded_and_random_policies_of_a_users_preset(
    preset: str, tmp_path, monkeypatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)
    means = {}
    for policy in ("hardcoded", "random"):
        main(["eval", "--policy", policy, "--preset", str(PRESETS / preset),
              "--episodes", "8", "--json"])  # fmt: skip
        result = json.loads(capsys.readouterr().out)
        assert result["env_id"] == ENV_IDS[preset]
        means[policy] = result["mean"]
    assert means["hardcoded"] > means["random"], means  # heading for the target pays


def test_evaluate_takes_a_policy_a_run_or_a_plain_callable() -> None:
    tree = graft.load_policy("hardcoded", preset=PRESETS / "reach.yaml")
    by_policy = graft.evaluate(tree, episodes=3, seed=5)
    # A bare batched callable needs its environment named.
    by_callable = graft.evaluate(tree.act, env="usertask.envs:Reach1D-v0", episodes=3, seed=5)
    np.testing.assert_array_equal(by_policy.returns, by_callable.returns)
    assert by_policy.env_id == "usertask.envs:Reach1D-v0" and by_policy.returns.shape == (3,)
    # The tree reaches the target within the time limit: every episode reports it.
    np.testing.assert_array_equal(by_policy.metrics["reached"], [1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="pass env="):
        graft.evaluate(tree.act, episodes=1)
