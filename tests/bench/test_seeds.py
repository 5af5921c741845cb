"""bench/seeds.py: which seed folders a resumed benchmark keeps."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.seeds import REPO, asked, refuse_other_settings, trained_wall_s


def _summary(run_dir: Path, **fields: object) -> None:
    run_dir.mkdir(parents=True)
    (run_dir / "summary.json").write_text(json.dumps({"wall_s": 12.5, **fields}))


def test_a_finished_training_is_kept_and_an_interrupted_or_missing_one_is_not(tmp_path) -> None:
    _summary(tmp_path / "finished", interrupted=False)
    _summary(tmp_path / "interrupted", interrupted=True)
    (tmp_path / "started").mkdir()  # stopped before its summary
    assert trained_wall_s(tmp_path / "finished") == 12.5
    assert trained_wall_s(tmp_path / "interrupted") is None
    assert trained_wall_s(tmp_path / "started") is None
    assert trained_wall_s(tmp_path / "absent") is None


def test_a_folder_trained_with_other_settings_is_refused_in_one_line_and_left_as_it_is(tmp_path):
    preset = str(REPO / "bench" / "tasks" / "pendulum.yaml")
    request = asked(preset, 3, overrides=["td3.tau=0.01"], env_steps=30_000)
    assert request["preset"] == "bench/tasks/pendulum.yaml"  # another checkout resumes it
    run_dir = tmp_path / "s3"
    _summary(run_dir, interrupted=False)
    (tmp_path / "s3.request.json").write_text(json.dumps(request))
    refuse_other_settings({run_dir: request})  # the same settings: resumed
    refuse_other_settings({run_dir: asked(preset, 3, overrides=["td3.tau=0.02", "td3.tau=0.01"],
                                          env_steps=30_000)})  # fmt: skip
    quick = asked(preset, 3, overrides=["td3.tau=0.01", "learning_starts=200"], env_steps=600)
    with pytest.raises(SystemExit) as refused:
        refuse_other_settings({tmp_path / "s2": quick, run_dir: quick})
    line = str(refused.value)
    assert "\n" not in line and str(run_dir) in line and "fresh --out" in line
    assert "env_steps 30000 there, 600 now" in line
    assert "--set learning_starts unset there, 200 now" in line
    assert (run_dir / "summary.json").exists()  # nothing removed
    reselected = asked(preset, 3, overrides=["td3.tau=0.01", "selection.z=3"], env_steps=30_000)
    refuse_other_settings({run_dir: reselected}, ignoring=("selection.",))
    with pytest.raises(SystemExit):
        refuse_other_settings({run_dir: reselected})
    budget = asked(preset, 3, overrides=["td3.tau=0.01"], env_steps=None)  # the preset's
    (tmp_path / "s3.request.json").write_text(json.dumps(budget))
    refuse_other_settings({run_dir: asked(preset, 3, overrides=["td3.tau=0.01"], env_steps=20_000)})
    with pytest.raises(SystemExit):
        refuse_other_settings({run_dir: request})  # 30,000: not the preset's 20,000
    (tmp_path / "s3.request.json").unlink()  # a folder from before the record
    refuse_other_settings({run_dir: quick})
