"""The example user projects in examples/, each installed as its own distribution (the
Makefile and tests/conftest.py install them with ``pip install -e``): their trees behave as
their READMEs say, every preset trains for a tiny budget, and `graft eval` loads the runs.

Real parts throughout: a local Ray cluster, the replay server process, the learner.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

# Imported at collection: importing MuJoCo starts a child process (ctypes finding OpenGL),
# which `make test-fast` refuses inside a test.
import gymnasium.envs.mujoco.half_cheetah_v5  # noqa: F401
import numpy as np
import pytest
import ray
import yaml

import graft
from graft.cli import main
from graft.config import load_preset

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
DISTRIBUTIONS = {
    "mountaincar": "graft-example-mountaincar 0.1.0",
    "cartpole": "graft-example-cartpole 0.1.0",
    "lunarlander": "graft-example-lunarlander 0.1.0",
    "halfcheetah": "graft-example-halfcheetah 0.1.0",
    "heldout": "graft-example-heldout 0.1.0",
}
TINY = {
    "env_steps": 300,
    "learning_starts": 100,
    "steps_per_insert": 4,
    "slack_env_steps": 16,
    "publish_every": 20,
    "eval_every": 300,
    "eval_episodes": 1,
    "checkpoint_every": 10_000,
}
"""Every preset's budget cut to seconds; the sections' own counts below."""
SECTIONS = {
    "td3": {"batch_size": 32, "burn_in_updates": 10, "frozen_actor_updates": 10},
    "pretrain": {"demo_steps": 100, "pretrain_updates": 20},
    # 250: the learner logs every 250th update's losses, the margin loss among them.
    "dqn": {"batch_size": 32, "burn_in_updates": 250, "epsilon_decay_env_steps": 200},
    # The recipe's final selection: 2 episodes each for the policy and the tree, not 30.
    "selection": {"episodes": 2},
}
BY_CLI = [
    "mountaincar/presets/backbone.yaml",
    "cartpole/presets/ddqn-demos.yaml",
    "lunarlander/presets/recipe.yaml",
]
"""Trained by `graft train`; every other preset through `graft.train`."""
FRESH = "lunarlander/presets/recipe.yaml"
"""The one of BY_CLI trained in a fresh process (the others through the same CLI in this
process: a fresh process costs seconds of imports and a Ray driver each)."""
# The held-out tasks' presets differ from the others only in their environment: one of
# them (Reacher's 50-step episodes, the quickest) stands for the four here; their trees are
# tested in test_heldout.py.
HELDOUT_SMOKE = "heldout/presets/reacher.yaml"
PRESETS = sorted(
    str(p.relative_to(EXAMPLES))
    for p in EXAMPLES.glob("*/presets/*.yaml")
    if not p.is_relative_to(EXAMPLES / "heldout") or str(p.relative_to(EXAMPLES)) == HELDOUT_SMOKE
)


def _tiny(preset: str) -> dict:
    """Overrides for the sections the preset sets (a section it does not set keeps its
    defaults, and some methods refuse fields they do not use)."""
    data = yaml.safe_load((EXAMPLES / preset).read_text())
    algorithm = data.get("algorithm") or load_preset(EXAMPLES / preset).algorithm
    # A preset without an algorithm trains with graft's default recipe, which sets the
    # section of its method.
    used = set(data) | ({"dqn"} if algorithm == "ddqn" else {"td3"})
    if "algorithm" not in data:
        used.add("selection")
    sections = {name: dict(fields) for name, fields in SECTIONS.items() if name in used}
    if algorithm != "pretrain_td3":
        sections.pop("pretrain", None)
    return {**TINY, **sections}


def _check_run(run_dir: Path, preset: str) -> None:
    summary = json.loads((run_dir / "summary.json").read_text())
    assert 300 - 16 <= summary["env_steps"] <= 300, summary
    assert summary["updates"] > 0 and np.isfinite(summary["final_eval_return_mean"])
    recorded = yaml.safe_load((run_dir / "config.yaml").read_text())
    example = preset.split("/")[0]
    assert DISTRIBUTIONS[example] in recorded["versions"]["task"].values()


def test_the_examples_are_installed_as_their_own_distributions() -> None:
    from importlib.metadata import distribution

    for example, installed in DISTRIBUTIONS.items():
        name, version = installed.split()
        assert distribution(name).version == version
        assert (EXAMPLES / example / "README.md").is_file()


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("preset", sorted(set(PRESETS) - set(BY_CLI)))
def test_every_example_preset_trains_and_its_run_evaluates(
    preset: str, ray_local, tmp_path, monkeypatch, capsys
) -> None:
    monkeypatch.chdir(tmp_path)  # neither the example's folder nor graft's
    run = graft.train(EXAMPLES / preset, run_dir=tmp_path / "run", **_tiny(preset))
    _check_run(run.run_dir, preset)
    main(["eval", "--policy", str(run.run_dir), "--episodes", "1", "--json"])
    result = json.loads(capsys.readouterr().out)
    assert result["env_id"] == run.config.env_id and np.isfinite(result["mean"])


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


def _set_flags(overrides: dict) -> list[str]:
    flags = []
    for key, value in overrides.items():
        if isinstance(value, dict):
            flags += [f"--set={key}.{field}={v}" for field, v in value.items()]
        else:
            flags.append(f"--set={key}={value}")
    return flags


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize("preset", BY_CLI)
def test_graft_train_of_an_example_by_the_cli_and_eval(
    preset: str, ray_local, tmp_path, monkeypatch, capsys
) -> None:
    """As the examples' READMEs say: `graft train --preset examples/...` (FRESH in a fresh
    process), then `graft eval` (a fresh `graft eval` of a user's run: test_own_task)."""
    address = ray.get_runtime_context().gcs_address  # join the session's cluster
    run_dir = tmp_path / "run"
    args = ["train", "--preset", str(EXAMPLES / preset), "--address", address,
            "--run-dir", str(run_dir), "--no-progress", *_set_flags(_tiny(preset))]  # fmt: skip
    if preset == FRESH:
        train = _graft(args, cwd=tmp_path)
        assert train.returncode == 0, train.stderr[-3000:]
        stderr = train.stderr
    else:
        monkeypatch.chdir(tmp_path)
        main(args)
        stderr = capsys.readouterr().err
    _check_run(run_dir, preset)
    if preset.endswith("recipe.yaml"):  # no algorithm named: said in one line
        assert "no algorithm: graft's default recipe for continuous actions" in stderr
        recorded = yaml.safe_load((run_dir / "config.yaml").read_text())
        assert (recorded["recipe"], recorded["algorithm"]) == ("continuous", "backbone_td3")
    if preset.endswith("ddqn-demos.yaml"):
        # The burn-in trained on the tree's demonstrations, with the margin loss towards it.
        with (run_dir / "metrics.csv").open() as f:
            margin = [float(r["value"]) for r in csv.DictReader(f) if r["key"] == "losses/margin"]
        assert margin and all(np.isfinite(margin))
    main(["eval", "--policy", str(run_dir), "--episodes", "2", "--json"])
    assert np.isfinite(json.loads(capsys.readouterr().out)["mean"])


def test_the_energy_pumping_tree_reaches_the_flag_from_every_start() -> None:
    tree = graft.load_policy("hardcoded", preset=EXAMPLES / "mountaincar/presets/backbone.yaml")
    result = graft.evaluate(tree, episodes=5, seed=0)
    np.testing.assert_array_equal(result.metrics["reached"], np.ones(5))
    assert np.all((85.0 < result.returns) & (result.returns < 95.0)), result.returns


def test_the_cartpole_tree_writes_discrete_actions_and_balances_for_a_while() -> None:
    preset = EXAMPLES / "cartpole/presets/ddqn-demos.yaml"
    tree = graft.load_policy("hardcoded", preset=preset)
    obs = np.array([[0.0, 0.0, 0.0, 0.5], [0.0, 0.0, 0.0, -0.5]], np.float32)
    np.testing.assert_array_equal(tree(obs), [1, 0])  # falling right: push right
    assert tree(obs).dtype == np.int64
    returns = graft.evaluate(tree, episodes=5, seed=0).returns
    random = graft.evaluate(graft.load_policy("random", preset=preset), episodes=5, seed=0)
    assert returns.min() > 100 > random.returns.max()  # well past random, short of 500
    assert returns.max() < 500


LANDER = EXAMPLES / "lunarlander/presets/backbone.yaml"
# [x, y, vx, vy, angle, angular velocity, left leg, right leg] -> [main, lateral], by rule.
LANDER_RULES = {
    "coasting, upright and slow": ([0, 1, 0, -0.1, 0, 0, 0, 0], [-1.0, 0.0]),
    "both legs down: engines off": ([0, 0, 0, -0.5, 0, 0, 1, 1], [-1.0, 0.0]),
    "sinking fast: brake": ([0, 1, 0, -1.0, 0, 0, 0, 0], [1.0, 0.0]),
    "tilted counter-clockwise: turn back": ([0, 1, 0, 0, 0.5, 0, 0, 0], [-1.0, 1.0]),
    "tilted clockwise: turn back": ([0, 1, 0, 0, -0.5, 0, 0, 0], [-1.0, -1.0]),
    "tipping beats sinking": ([0, 1, 0, -1.0, 0.5, 0, 0, 0], [-1.0, 1.0]),
}


@pytest.mark.parametrize("obs, action", LANDER_RULES.values(), ids=LANDER_RULES.keys())
def test_the_lander_tree_answers_each_situation_by_its_rule(obs, action) -> None:
    tree = graft.load_policy("hardcoded", preset=LANDER)
    np.testing.assert_array_equal(tree(np.array(obs, np.float32)), action)


def test_the_lander_tree_is_mediocre_as_its_readme_says() -> None:
    """Far above random and short of LunarLander's 200: it lands about half the time."""
    result = graft.evaluate(graft.load_policy("hardcoded", preset=LANDER), episodes=50, seed=0)
    assert 100.0 <= result.mean <= 180.0, result.mean
    assert 0.3 <= np.mean(result.metrics["landed"]) <= 0.8


LANDER_DISCRETE = EXAMPLES / "lunarlander/presets/recipe-discrete.yaml"
DISCRETE = {(-1.0, 0.0): 0, (-1.0, -1.0): 1, (1.0, 0.0): 2, (-1.0, 1.0): 3}
"""[main, lateral] -> LunarLander's discrete action (nothing, left, main, right engine)."""


@pytest.mark.parametrize("obs, action", LANDER_RULES.values(), ids=LANDER_RULES.keys())
def test_the_discrete_lander_fires_the_engines_of_each_rule(obs, action) -> None:
    tree = graft.load_policy("hardcoded", preset=LANDER_DISCRETE)
    assert tree(np.array(obs, np.float32)) == DISCRETE[tuple(action)]


def test_the_discrete_lander_flies_as_the_continuous_one() -> None:
    """gymnasium's discrete engines are the continuous ones at full power, the only power
    the tree asks for: the same episodes, step for step."""
    continuous = graft.evaluate(graft.load_policy("hardcoded", preset=LANDER), episodes=3, seed=0)
    discrete = graft.load_policy("hardcoded", preset=LANDER_DISCRETE)
    np.testing.assert_allclose(
        graft.evaluate(discrete, episodes=3, seed=0).returns, continuous.returns
    )


CHEETAH = EXAMPLES / "halfcheetah/presets/recipe.yaml"
PITCH, BACK_THIGH, BACK_THIGH_SPEED = 1, 2, 11
"""Indices into HalfCheetah's observation: the body's pitch, the back thigh's angle and
its angular velocity (every other entry 0 below: standing level, joints at rest)."""
CHEETAH_RULES = {
    "rearing: both thighs lean back": ({PITCH: 1.2}, [1.0, 0, 0, 1.0, 0, 0]),
    "diving: both thighs lean back": ({PITCH: -1.2}, [-1.0, 0, 0, -1.0, 0, 0]),
    "tilted beats running": ({PITCH: 1.2, BACK_THIGH: 0.6}, [1.0, 0, 0, 1.0, 0, 0]),
    "stroke's front end: the back thigh turns back": ({BACK_THIGH: 0.6}, -1.0),
    "stroke's back end: the back thigh turns forward": ({BACK_THIGH: -0.7}, 1.0),
    "mid-stroke moving forward: keep pushing": ({BACK_THIGH_SPEED: 1.0}, 1.0),
    "mid-stroke moving back: keep pulling": ({BACK_THIGH_SPEED: -1.0}, -1.0),
}
"""Observation entries -> the whole action (tilted) or the back thigh's torque (running)."""


@pytest.mark.parametrize("entries, expected", CHEETAH_RULES.values(), ids=CHEETAH_RULES.keys())
def test_the_cheetah_tree_answers_each_situation_by_its_rule(entries, expected) -> None:
    obs = np.zeros(17, np.float32)
    for index, value in entries.items():
        obs[index] = value
    action = graft.load_policy("hardcoded", preset=CHEETAH)(obs)
    if isinstance(expected, list):
        np.testing.assert_array_equal(action, expected)
    else:  # running: the relay drives the back thigh, the PD law the others within ±1
        assert action[0] == expected and np.all(np.abs(action) <= 1.0), action


def test_the_cheetah_gait_runs_far_above_random_and_far_below_rl() -> None:
    """As its README says: the gait runs forwards (about 1,200 an episode), random loses ~270."""
    result = graft.evaluate(graft.load_policy("hardcoded", preset=CHEETAH), episodes=3, seed=0)
    random = graft.evaluate(graft.load_policy("random", preset=CHEETAH), episodes=3, seed=0)
    assert np.all((900.0 < result.returns) & (result.returns < 2000.0)), result.returns
    assert random.returns.max() < 0.0, random.returns
