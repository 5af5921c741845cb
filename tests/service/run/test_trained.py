"""A run folder's config loads from the folder alone, whatever preset it came from."""

from __future__ import annotations

import yaml

from service.run.config import load_preset
from service.run.orchestration.provenance import config_record
from service.run.trained import run_config


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
