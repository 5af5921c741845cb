"""A replay server started by `ReplayProcess` does not outlive its parent, even a SIGKILLed one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.service  # real server processes, or Ray

ROOT = Path(__file__).resolve().parents[2]
PARENT = """
from graft.replay_host.process import ReplayProcess
from tests.conftest import PENDULUM_SIGNATURE
server = ReplayProcess([{"name": "t", "max_size": 10, "signature": PENDULUM_SIGNATURE}])
print(server.process.pid, flush=True)
input()
"""


def _running(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


@pytest.mark.serial  # waits for the orphaned server to notice
def test_the_replay_server_stops_when_its_parent_is_killed() -> None:
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT], cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    server = int(parent.stdout.readline())  # type: ignore[union-attr]
    try:
        assert _running(server)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 60  # a hang guard: it notices within about a second
        while _running(server) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _running(server)
    finally:
        if _running(server):
            os.kill(server, signal.SIGKILL)


@pytest.mark.parametrize("pidfds", [True, False], ids=["pidfd", "no pidfds (seccomp)"])
def test_the_death_of_the_starting_process_is_seen_with_or_without_pidfds(
    monkeypatch, pidfds
) -> None:
    """A forked server's starting process is its grandparent; a container's seccomp may
    refuse pidfd_open. Either way a check sees that process die, and only then."""
    from service.replay.server.serve import _death_check

    if not pidfds:

        def refused(pid: int) -> int:
            raise PermissionError(1, "Operation not permitted")

        monkeypatch.setattr(os, "pidfd_open", refused)
    starter = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        gone = _death_check(starter.pid)
        assert not gone()
        assert not _death_check(os.getppid())()  # our own parent, alive
    finally:
        starter.kill()
        starter.wait()
    assert gone()
