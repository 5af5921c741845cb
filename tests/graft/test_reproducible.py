"""Reproducible mode: the same seed rewrites the same metrics.csv, through real parts (a
local Ray, actors, the replay server process, the evaluator); the default stays
asynchronous."""

from __future__ import annotations

import pytest

from graft.cli.parser import build_parser
from graft.cli.train import train_overrides
from graft.config import load_preset, preset_names
from graft.orchestration.launcher import train


def tiny(**overrides):
    return load_preset(
        "pendulum-td3",
        env_steps=600,
        learning_starts=200,
        eval_every=200,
        eval_episodes=2,
        publish_every=20,
        checkpoint_every=1000,
        num_actors=2,
        envs_per_actor=2,
        steps_per_insert=4,
        slack_env_steps=16,
        **{"td3.hidden_sizes": [32, 32], "td3.batch_size": 32},
        **overrides,
    )


@pytest.mark.slow
def test_a_seed_rewrites_the_same_metrics_csv(ray_local, tmp_path):
    runs = [train(tiny(reproducible=True), run_dir=tmp_path / f"run{k}", progress=False)
            for k in range(2)]  # fmt: skip
    first, second = (r.run_dir / "metrics.csv" for r in runs)
    # Losses and every evaluation (of weights after up to 400 updates) are in the file.
    lines = first.read_text().splitlines()
    assert lines[0] == "env_steps,updates,key,value", lines[0]
    keys = {line.split(",")[2] for line in lines[1:]}
    assert {"losses/critic", "eval/return_mean"} <= keys, keys
    assert sum(line.split(",")[2] == "eval/return_mean" for line in lines) >= 3
    assert first.read_bytes() == second.read_bytes()
    # Wall-clock measurements are kept apart, in timing.csv.
    assert not any(k.startswith("perf/") for k in keys)
    assert "perf/updates_per_s" in (runs[0].run_dir / "timing.csv").read_text()
    for r in runs:
        assert r.summary["mode"] == "reproducible"
        assert (r.summary["env_steps"], r.summary["updates"]) == (600, 400)
        assert "reproducible: true" in (r.run_dir / "config.yaml").read_text()
    # Both actors took part, and adopted published weights.
    assert all(n == 300 for n in runs[0].summary["actor_env_steps"])
    assert all(v >= 1 for v in runs[0].summary["actor_last_version"])


def test_the_default_mode_is_asynchronous():
    assert not any(load_preset(name).reproducible for name in preset_names())
    args = build_parser().parse_args(["train", "--preset", "pendulum-td3"])
    assert train_overrides(args)["reproducible"] is None
    args = build_parser().parse_args(["train", "--reproducible"])
    assert train_overrides(args)["reproducible"] is True
