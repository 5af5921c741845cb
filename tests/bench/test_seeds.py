"""bench/seeds.py: which seed folders a resumed benchmark keeps."""

from __future__ import annotations

import json
from pathlib import Path

from bench.seeds import trained_wall_s


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
