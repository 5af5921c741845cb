"""Ctrl-C (or SIGTERM) on `graft train`: a final checkpoint and summary, one line, and no
process left.

A real `graft train` subprocess with its own local Ray instance and replay server; the test
signals only that process (and, if the test itself fails, kills what that process started).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from learner.checkpoint import latest_checkpoint, load_checkpoint
from tests.tools.exec_with import command as exec_with

# Real server processes and a Ray instance of its own; `serial`: it waits on a run's clock
# (a signal sent mid-run, processes given time to end), and the real-time lane beside the
# parallel part has the idle CPU for its two Ray starts.
pytestmark = [pytest.mark.service, pytest.mark.serial]

ROOT = Path(__file__).resolve().parents[2]
STARTUP_LIMIT_S = 600.0
"""Only a guard against a hang: how long the run may take to log its first metrics row."""


def _children() -> dict[int, list[int]]:
    """Parent pid -> its child pids, from /proc."""
    tree: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue  # exited meanwhile
            tree.setdefault(ppid, []).append(int(entry.name))
    return tree


def _descendants(pid: int) -> set[int]:
    tree, found, todo = _children(), set(), [pid]
    while todo:
        for child in tree.get(todo.pop(), []):
            found.add(child)
            todo.append(child)
    return found


def _running(pid: int) -> bool:
    """Alive and not a zombie waiting to be reaped."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _wait_until_gone(pids: set[int], limit_s: float = 120.0) -> set[int]:
    """The pids still running once all have exited or `limit_s` has passed (a hang guard)."""
    deadline = time.monotonic() + limit_s
    while (alive := {p for p in pids if _running(p)}) and time.monotonic() < deadline:
        time.sleep(0.5)
    return alive


@pytest.mark.parametrize(
    "sig, status, word",
    [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
    ids=["ctrl-c", "sigterm"],
)
def test_a_stop_signal_checkpoints_summarises_and_leaves_no_process(
    tmp_path, sig, status, word
) -> None:
    run_dir = tmp_path / "run"
    # RAY_ADDRESS names no cluster: `--address local` must start its own Ray regardless.
    env = {**os.environ, "PYTHONPATH": str(ROOT), "RAY_ADDRESS": "127.0.0.1:9"}
    argv = [
        sys.executable, "-m", "graft.cli", "train", "--preset", "pendulum-td3",
        "--address", "local", "--run-dir", str(run_dir), "--no-progress",
        "--env-steps", "10000000", "--actors", "1",
        "--set", "envs_per_actor=2", "--set", "learning_starts=100",
        "--set", "eval_every=200", "--set", "eval_episodes=1",
        "--set", "td3.hidden_sizes=[16, 16]", "--set", "td3.batch_size=32",
    ]  # fmt: skip
    # A shell's background job inherits SIGINT ignored, and a Python started that way never
    # raises KeyboardInterrupt: the run gets Ctrl-C's default, as from a terminal.
    process = subprocess.Popen(
        [*exec_with("--default-sigint"), *argv],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    started: set[int] = set()
    try:
        metrics, deadline = run_dir / "metrics.csv", time.monotonic() + STARTUP_LIMIT_S
        # Stopped once the learner has updated (past learning_starts=100 env steps), however
        # slowly a loaded machine gets there.
        while not (metrics.exists() and "losses/" in metrics.read_text()):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "no learner update: the run did not start"
            time.sleep(0.5)
        started = _descendants(process.pid)
        replay = {p for p in started if "graft.cli.replay serve" in _cmdline(p)}
        raylets = {p for p in started if "raylet" in _cmdline(p)}
        assert len(replay) == 1 and raylets, {p: _cmdline(p) for p in started}

        process.send_signal(sig)
        _, err = process.communicate(timeout=300)
    finally:
        if process.poll() is None:  # the test failed: leave nothing behind
            process.kill()
            process.wait()
        for pid in _wait_until_gone(started, limit_s=0.0 if process.returncode == status else 5.0):
            os.kill(pid, signal.SIGKILL)

    summary = json.loads((run_dir / "summary.json").read_text())
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    steps = summary["env_steps"]
    assert process.returncode == status, err
    assert "Traceback" not in err, err
    assert (
        f"graft train: {word} at {steps} env steps; checkpoint {checkpoint}, "
        f"summary {run_dir / 'summary.json'}"
    ) in err.splitlines(), err
    assert "RAY_ADDRESS" not in err  # --address local was given: nothing to say
    assert summary["interrupted"] is True and steps >= 100 and summary["updates"] > 0
    # The final checkpoint holds the state the message and the summary report.
    saved = load_checkpoint(checkpoint)["loop"]
    assert (saved["env_steps"], saved["updates"]) == (steps, summary["updates"])
    # Nothing the run started outlives it: the replay server, Ray's processes and workers.
    assert _wait_until_gone(started) == set(), {p: _cmdline(p) for p in started}
    assert not any(_running(p) for p in replay)
