"""A disk that fills during `graft train`: the run stops in one line naming the file, the
space left and the env steps reached, with status 1; the last good checkpoint stays whole,
no temporary file is left, summary.json says so; `--resume` once space is back removes a
stale temporary and finishes the run.

A real `graft train` subprocess (its own Ray and replay server) with its run folder on a
4 MiB tmpfs, filled by the test once the first checkpoint is written.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from learner.checkpoint import latest_checkpoint, load_checkpoint
from tests.tools.small_disk import small_disk

pytestmark = [pytest.mark.service, pytest.mark.serial, pytest.mark.long]

ROOT = Path(__file__).resolve().parents[2]
LEFT_FREE = 100 * 1024
"""What the test leaves free: less than one checkpoint (about 220 KB), more than the replay
log and metrics.csv grow by before the learner's next checkpoint."""


def _argv(run_dir: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "graft.cli", "train", "--preset", "pendulum-td3",
        "--address", "local", "--run-dir", str(run_dir), "--no-progress", "--actors", "1",
        "--env-steps", "3000", "--set", "envs_per_actor=2", "--set", "learning_starts=100",
        "--set", "eval_every=1000", "--set", "eval_episodes=1", "--set", "checkpoint_every=100",
        "--set", "td3.hidden_sizes=[64, 64]", "--set", "td3.batch_size=32", *extra,
    ]  # fmt: skip


def _fill(disk: Path, leave: int) -> Path:
    filler = disk / "filler"
    free = shutil.disk_usage(disk).free
    with open(filler, "wb") as f:
        f.write(b"\0" * max(free - leave, 0))
    return filler


def test_a_full_disk_stops_the_run_cleanly_and_resume_goes_on(tmp_path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RAY_ADDRESS": "127.0.0.1:9"}
    with small_disk(tmp_path / "disk", "4m") as disk:
        run_dir = disk / "run"
        process = subprocess.Popen(
            _argv(run_dir), cwd=tmp_path, env=env, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 600
            while latest_checkpoint(run_dir / "checkpoints") is None:
                assert process.poll() is None, process.communicate()
                assert time.monotonic() < deadline, "no checkpoint: the run did not start"
                time.sleep(0.2)
            filler = _fill(disk, LEFT_FREE)
            _, err = process.communicate(timeout=600)
        finally:
            if process.poll() is None:
                process.kill()
                process.wait()
        lines = err.strip().splitlines()
        assert process.returncode == 1, err
        assert "Traceback" not in err, err
        summary = json.loads((run_dir / "summary.json").read_text())
        last = latest_checkpoint(run_dir / "checkpoints")
        assert summary["stopped"].startswith("disk full writing ")
        assert summary["last_checkpoint"] == str(last)
        assert lines[-1] == f"graft train: stopped: {summary['stopped']}"
        assert (
            f" at {summary['env_steps']} env steps; the last good checkpoint is {last}"
            in (lines[-1])
        )
        assert " KiB free) " in lines[-1] or " B free) " in lines[-1]
        assert not list(run_dir.rglob("*.tmp")), list(run_dir.rglob("*.tmp"))
        assert load_checkpoint(last)["loop"]["updates"] > 0  # whole: torch reads it

        # Space back, and a stale temporary as a killed run would leave: resume removes it.
        filler.unlink()
        stale = run_dir / "checkpoints" / "ckpt-999999999.pt.tmp"
        stale.write_bytes(b"half a checkpoint")
        resumed = subprocess.run(
            _argv(run_dir, "--resume"), cwd=tmp_path, env=env, capture_output=True,
            text=True, timeout=600,
        )  # fmt: skip
        assert resumed.returncode == 0, resumed.stderr
        assert f"removed {stale}, left half-written by a run that stopped mid-write" in (
            resumed.stdout
        )
        assert not stale.exists()
        assert json.loads((run_dir / "summary.json").read_text())["env_steps"] >= 3000
