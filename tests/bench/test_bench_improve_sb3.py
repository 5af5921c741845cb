"""bench/improve_sb3.py: stable-baselines3's arms of bench/improve.py — their settings fit
their tasks, a tiny run trains in its own process and is scored on the held-out episodes,
and the task table shows them beside graft's arms."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from bench import improve, improve_report, improve_sb3
from graft.seeds import evaluation_seed, held_out_seed

try:
    import stable_baselines3
except ImportError:  # a bench-only extra: `make setup` installs it
    stable_baselines3 = None
needs_sb3 = pytest.mark.skipif(
    stable_baselines3 is None,
    reason="stable-baselines3 is not installed (pip install -e '.[bench]'; make setup does)",
)


def _row(seed: int, tree: float, final: float) -> improve.SeedRow:
    return improve.SeedRow(seed, tree, final, 100.0, [1000], [1.0], 3000, 10.0)


MUJOCO = {"halfcheetah", "hopper", "walker2d", "reacher"}
"""Tasks whose environment's first make probes its GL library in a subprocess."""


@needs_sb3
@pytest.mark.parametrize(
    ("task", "arm"),
    [
        pytest.param(task, arm, marks=[pytest.mark.service] if task in MUJOCO else [])
        for task, arm in sorted(improve_sb3.HYPERPARAMETERS)
    ],
)
def test_every_setting_is_for_a_task_whose_actions_its_algorithm_takes(task, arm):
    env = improve.load_preset(improve.TASKS[task]).env_spec().make()
    discrete = isinstance(env.action_space, gym.spaces.Discrete)
    assert discrete == (arm == "sb3-dqn")
    settings, source = improve_sb3.HYPERPARAMETERS[(task, arm)]
    model = improve_sb3.build(arm, settings, env, seed=0)  # stable-baselines3 takes each key
    assert type(model).__name__ == improve_sb3.ALGORITHMS[arm] and source
    act = improve_sb3.acting(model)(np.stack([env.observation_space.sample()] * 3))
    assert act.shape[0] == 3 and all(env.action_space.contains(a) for a in act)


def test_a_reference_arm_a_task_cannot_take_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as stopped:
        improve.main(["--task", "cartpole", "--arm", "sb3-td3", "--out", "/nonexistent"])
    assert stopped.value.code == 2
    assert "--arm sb3-td3: not for task cartpole" in capsys.readouterr().err.splitlines()[-1]


def test_the_task_row_shows_each_reference_arm_and_the_recipes_margin_over_the_best():
    tree = [100.0, 90.0, 110.0]
    recipe = [_row(s, tree[s], f) for s, f in enumerate([150.0, 140.0, 125.0])]
    scratch = [_row(s, tree[s], f) for s, f in enumerate([130.0, 120.0, 140.0])]
    td3 = [_row(s, tree[s], f) for s, f in enumerate([160.0, 120.0])]  # 2 seeds, mean 140
    sac = [_row(s, tree[s], f) for s, f in enumerate([100.0, 100.0])]
    arms = {"scratch": scratch, "sb3-td3": td3, "sb3-sac": sac, "recipe": recipe}
    row = improve_report.compare("t", arms)
    # graft's margin is untouched: over the better of the tree and graft's from scratch
    assert row["better"] == "scratch" and row["margin"] == pytest.approx(25.0 / 3)
    # over the best stable-baselines3 arm (TD3), paired on the seeds both ran
    assert row["best_reference"] == "sb3-td3" and row["reference_margin_seeds"] == [0, 1]
    assert row["reference_margin"] == pytest.approx((-10.0 + 20.0) / 2)
    assert all(np.isnan(row["reference_margin_ci"]))  # 2 seeds: no interval
    header, _, line = improve_report.task_table([row]).splitlines()
    assert "from scratch (SB3), mean [95 % CI] (seeds)" in header
    assert "| SB3 TD3 140.0 (2); SB3 SAC 100.0 (2) |" in line
    assert line.endswith("| 3/3 | +5.0 (no CI below 3 seeds) vs SB3 TD3 |")
    alone = improve_report.compare("t", {"sb3-sac": sac})  # no recipe ran: no margins
    assert improve_report.task_table([alone]).splitlines()[-1].endswith("| - | 0/0 | - |")


@needs_sb3
@pytest.mark.service  # a process per seed
@pytest.mark.timeout(240)
def test_a_tiny_run_trains_in_its_own_process_and_plays_the_held_out_episodes(tmp_path, capsys):
    argv = ["--task", "pendulum", "--arm", "sb3-sac", "--quick", "--env-steps", "300"]
    (task,) = improve.main([*argv, "--out", str(tmp_path)])
    run = tmp_path / "pendulum" / "sb3-sac" / "s0"
    saved = json.loads((run / "eval.json").read_text())
    summary = json.loads((run / "summary.json").read_text())
    assert summary["env_steps"] == 300 and summary["source"].endswith("sac.yml@c94924e Pendulum-v1")
    assert summary["evaluations"]["env_steps"] == [300]  # --quick: every 300 steps, 2 episodes
    assert summary["evaluations"]["seed"] == evaluation_seed(0)
    assert saved["seed"] == held_out_seed(0) and len(saved["returns"]) == improve.QUICK_EPISODES
    # The saved model, played again on the held-out episodes, gives exactly those returns.
    model = stable_baselines3.SAC.load(run / "model.zip", device="cpu")
    replayed = improve.graft.evaluate(
        improve_sb3.acting(model), env="Pendulum-v1", episodes=10, seed=held_out_seed(0)
    )
    assert replayed.returns.tolist() == saved["returns"]
    assert task["sb3-sac"]["mean"] == pytest.approx(np.mean(saved["returns"]))
    tree = improve.graft.load_policy("hardcoded", preset=improve.TASKS["pendulum"])
    on_held_out = improve.graft.evaluate(tree, episodes=10, seed=held_out_seed(0)).mean
    assert task["tree"] == pytest.approx(on_held_out)  # the tree on the same episodes
    assert "| pendulum | sb3-sac: sb3 SAC | 300 |" in capsys.readouterr().out
    # A finished seed is read back, not trained again.
    trained = (run / "model.zip").stat().st_mtime_ns
    (again,) = improve.main([*argv, "--out", str(tmp_path)])
    assert (run / "model.zip").stat().st_mtime_ns == trained
    assert again["sb3-sac"]["mean"] == task["sb3-sac"]["mean"]
