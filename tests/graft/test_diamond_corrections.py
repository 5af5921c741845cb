"""Trained runs deployed in the obtain-diamond tree: each loads at the leaf its task
trains, and bench/diamond.py runs a short world with them beside the tree alone."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from graft.config import load_preset
from graft.orchestration.provenance import config_record
from graft.registry import make_builder
from graft.trained import load_corrections
from learner.checkpoint import save_checkpoint
from minecraft.agent.corrections import DROP_OBS_DIM
from minecraft.agent.travel_control import OBS_DIM

ROOT = Path(__file__).resolve().parents[2]


def _untrained_run(folder: Path, preset: str, **overrides: object) -> Path:
    """A run folder as training leaves one: its config and a checkpoint (not trained)."""
    config = load_preset(preset, **overrides)
    folder.mkdir(parents=True)
    (folder / "config.yaml").write_text(config_record(config))
    learner = make_builder(config).make_learner()
    save_checkpoint(folder / "checkpoints", {"algorithm": learner.state_dict()}, updates=0)
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("runs")
    return {
        "travel": _untrained_run(
            base / "travel", "minecraft-backbone", **{"td3.hidden_sizes": [16, 16]}
        ),
        "drops": _untrained_run(base / "drops", "minecraft-drops", **{"dqn.hidden_sizes": [16]}),
        "pendulum": _untrained_run(base / "pendulum", "pendulum-td3"),
    }


def test_each_run_corrects_the_leaf_it_trained_for(runs: dict[str, Path]) -> None:
    travel = load_corrections([runs["travel"]])
    assert travel.travel is not None and travel.drops is None
    action = travel.travel(np.zeros(OBS_DIM, np.float32))
    assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)
    both = load_corrections([runs["drops"], runs["travel"]])
    assert both.travel is not None and both.drops is not None
    assert int(both.drops(np.zeros(DROP_OBS_DIM, np.float32))) in (0, 1)
    with pytest.raises(ValueError, match="corrects no leaf"):
        load_corrections([runs["pendulum"]])
    with pytest.raises(ValueError, match="a second run for the travel leaf"):
        load_corrections([runs["travel"], runs["travel"]])
    assert travel.travel_activities is None  # every walk
    searching = load_corrections([runs["travel"]], ["searching"])
    assert searching.travel_activities == {"searching"}
    with pytest.raises(ValueError, match="unknown activity 'walking': one of travel, "):
        load_corrections([runs["travel"]], ["walking"])
    with pytest.raises(
        ValueError, match=r"travel activities \['searching'\] given, but no travel run"
    ):
        load_corrections([runs["drops"]], ["searching"])


@pytest.mark.service  # world servers
def test_a_short_world_with_controllers_beside_the_tree_alone(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    png = tmp_path / "time.png"
    out = subprocess.run(
        [sys.executable, str(ROOT / "bench" / "diamond.py"), "--worlds", "1",
         "--first-seed", "4", "--procs", "1", "--max-ticks", "400", "--png", str(png),
         "--controller", str(runs["travel"]), "--controller", str(runs["drops"]),
         "--travel-while", "searching"],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    ).stdout  # fmt: skip
    tree = out.split("### tree alone")[1].split("### tree + corrections")[0]
    corrected = out.split("### tree + corrections")[1].split("\nwall ")[0]
    row = next(line for line in corrected.splitlines() if line.startswith("| 4 |"))
    left, decided = (int(v) for v in row.split("|")[8].split("/"))
    assert decided >= 1 and 0 <= left <= decided  # the drops policy was asked
    assert "| 4 |" in tree and "| 0 / 0 |" in tree  # the tree alone asks nobody
    assert "paired on 1 worlds" in out and png.stat().st_size > 0
