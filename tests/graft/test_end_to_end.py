"""A tiny-budget run through real parts: Ray actors -> replay server process -> learner."""

from __future__ import annotations

import csv
import json

import pytest

from graft.cli import main
from graft.config import load_preset
from graft.orchestration.launcher import train


def tiny_preset(*, env_steps: int):
    return load_preset(
        "pendulum-td3",
        env_steps=env_steps,
        learning_starts=200,
        eval_every=200,
        eval_episodes=2,
        publish_every=20,
        checkpoint_every=100,
        num_actors=2,
        envs_per_actor=2,
        steps_per_insert=4,
        slack_env_steps=16,
        **{"td3.hidden_sizes": [32, 32], "td3.batch_size": 32},
    )


def test_pendulum_td3_end_to_end_then_resume(ray_local, tmp_path, capsys):
    config = tiny_preset(env_steps=600)
    result = train(config, run_dir=tmp_path, progress=False)
    s = result.summary
    # Transitions arrived: the table's insert counter reached the budget.
    assert s["env_steps"] == 600
    assert sum(s["actor_env_steps"]) == 600
    # The learner updated once per env step after warm-up, and published new versions.
    assert s["updates"] == 400
    assert s["policy_version"] >= 400 // 20
    # Every actor adopted weights newer than the initial version 0.
    assert all(v >= 1 for v in s["actor_last_version"]), s
    assert result.evaluations, "the evaluator never reported"
    for name in ("metrics.csv", "learning_curve.png", "summary.json", "config.yaml"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert sorted(p.name for p in (tmp_path / "checkpoints").glob("*.pt"))[-1] == (
        "ckpt-000000400.pt"
    )
    # The default mode is asynchronous, and says so; its metrics carry wall-clock times.
    assert s["mode"] == "asynchronous"
    assert "reproducible: false" in (tmp_path / "config.yaml").read_text()
    with (tmp_path / "metrics.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert rows and all(float(row["wall_s"]) >= 0 for row in rows)
    keys = {row["key"] for row in rows}
    assert {"losses/critic", "eval/return_mean", "perf/updates_per_s"} <= keys
    assert {"perf/policy_lag", "perf/sample_age_versions", "perf/sample_age_s"} <= keys

    # `graft eval` loads the run folder and a checkpoint file of it alike.
    for policy in (tmp_path, tmp_path / "checkpoints" / "ckpt-000000400.pt"):
        main(["eval", "--policy", str(policy), "--episodes", "1", "--json"])
        result = json.loads(capsys.readouterr().out)
        assert result["env_id"] == "Pendulum-v1" and result["mean"] < 0, result
    with pytest.raises(SystemExit, match="no checkpoint under"):
        main(["eval", "--policy", str(tmp_path / "checkpoints"), "--episodes", "1"])

    # Resume: counters continue from the checkpoint, and the run's replay table comes
    # back (600 inserts, no refill): updates go on to the 800 its rate limiter holds for
    # 1000 env steps, less the batches the first learner had prefetched but not used.
    longer = tiny_preset(env_steps=1000)
    resumed = train(longer, run_dir=tmp_path, resume=True, progress=False).summary
    assert resumed["replay_restored"]["inserts"] == 600
    assert 800 - longer.prefetch <= resumed["updates"] <= 800, resumed
    assert resumed["env_steps"] <= 1000 and sum(resumed["actor_env_steps"]) <= 400
    assert resumed["policy_version"] > s["policy_version"]
    assert json.loads((tmp_path / "summary.json").read_text())["updates"] == resumed["updates"]
