"""A run folder's config loads from the folder alone, whatever preset it came from."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
import yaml

from graft.config import load_preset
from graft.orchestration.provenance import config_record
from graft.registry import make_builder
from graft.trained import run_config
from learner.checkpoint import save_checkpoint
from learner.loop import to_tensors
from tests.conftest import pendulum_batch


def test_config_of_a_run_from_a_yaml_preset_loads_without_the_yaml(tmp_path) -> None:
    preset = tmp_path / "presets" / "my.yaml"
    preset.parent.mkdir()
    preset.write_text("env_id: Pendulum-v1\nalgorithm: td3\nenv_steps: 5000\ntd3:\n  gamma: 0.9\n")
    config = load_preset(preset, seed=3)
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(config_record(config))
    preset.unlink()  # the run folder alone must do: no preset named 'my' exists
    loaded = run_config(run)
    assert loaded == config
    assert loaded.preset == "my" and loaded.seed == 3 and loaded.td3.gamma == 0.9
    assert str(preset.parent) in loaded.import_path
    recorded = yaml.safe_load((run / "config.yaml").read_text())
    assert recorded["versions"]["graft-rl"] and "task" not in recorded["versions"]


def test_config_recorded_without_a_hardcoded_policy_takes_its_presets(tmp_path) -> None:
    data = load_preset("pendulum-backbone").to_dict()
    del data["hardcoded_policy"], data["obs_wrapper"], data["import_path"]
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(data))
    assert run_config(tmp_path).hardcoded_policy == "actors.trees.pendulum:swing_up"


@pytest.mark.service  # a fresh interpreter: this one imported torch._dynamo long ago
def test_a_run_loaded_to_act_builds_no_optimiser(tmp_path) -> None:
    """`graft eval` and `graft.load_policy` build the run's learner to load its weights;
    its Adam optimisers are built only when it trains (building one imports
    torch._dynamo, 1.2 s of CPU), and the loaded policy acts as the trained one."""
    config = load_preset("pendulum-td3", **{"td3.hidden_sizes": [16, 16]})
    learner = make_builder(config).make_learner()
    learner.update(to_tensors(pendulum_batch(32)))  # trained: its optimisers hold state
    save_checkpoint(tmp_path / "checkpoints", {"algorithm": learner.state_dict()}, updates=1)
    (tmp_path / "config.yaml").write_text(config_record(config))
    obs = [0.5, -0.5, 0.25]
    script = (
        "import sys, json, graft; policy = graft.load_policy(sys.argv[1]); "
        "action = policy(__import__('numpy').array(json.loads(sys.argv[2]), 'float32')); "
        "print(json.dumps([action.tolist(), 'torch._dynamo' in sys.modules]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path), json.dumps(obs)],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    action, dynamo = json.loads(out.stdout.splitlines()[-1])
    assert not dynamo
    with torch.no_grad():
        expected = learner.actor(torch.tensor([obs])).numpy()[0]
    np.testing.assert_allclose(action, expected, rtol=1e-5, atol=1e-6)
