"""Server processes forked from a fork server (`service.forkserver`), against the plain
child processes they stand in for: the same arguments, environment, folder, output and exit
statuses, under the command's process title."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from service import forkserver

pytestmark = pytest.mark.service  # real processes

ROOT = Path(__file__).resolve().parents[2]
MODULE = "tests.tools.forkee"


@pytest.fixture(params=["forked", "plain"])
def mode(request, monkeypatch) -> str:
    monkeypatch.setattr(forkserver, "ENABLED", request.param == "forked")
    return request.param


def _start(tmp_path: Path, *argv: str) -> tuple[forkserver.Process, Path]:
    output = tmp_path / "out.log"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "FORKEE_X": "from the request"}
    if argv[0] == "sleep":  # a long title (a replay server's is several hundred characters)
        argv = (*argv, "x" * 2000)
    process = forkserver.start(MODULE, list(argv), env=env, output=str(output), cwd=str(tmp_path))
    return process, output


def _wait_for_output(process: forkserver.Process, output: Path) -> None:
    """Until the child's first line is whole: a line over 4 KiB may reach the file in
    more than one write, and a signal between them would cut it."""
    deadline = time.monotonic() + 30
    while not output.read_text().endswith("\n"):
        assert time.monotonic() < deadline and process.poll() is None
        time.sleep(0.02)


def _ppid(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def test_a_process_runs_the_modules_main_with_its_arguments_environment_and_folder(tmp_path, mode):
    process, output = _start(tmp_path, "sleep", "30")
    try:
        _wait_for_output(process, output)
        title = Path(f"/proc/{process.pid}/cmdline").read_bytes().replace(b"\0", b" ")
        assert f"-m {MODULE} sleep 30 {'x' * 2000}".encode() in title  # as `ps` shows it
        assert (_ppid(process.pid) == os.getpid()) == (mode == "plain")
    finally:
        process.terminate()
    assert process.wait(10) == -signal.SIGTERM
    seen = json.loads(output.read_text())
    assert seen["argv"] == seen["sys.argv"] == ["sleep", "30", "x" * 2000]
    assert seen["x"] == "from the request" and seen["cwd"] == str(tmp_path)


def test_a_long_title_fits_a_fork_server_of_a_small_environment(tmp_path, monkeypatch):
    """A title is written over the fork server's command line and environment: a small
    environment (a node's service manager's, a container's), or one that says to keep to
    the command line (SPT_NOENV, in Ray's workers), must not cut it short."""
    forkserver.close_all()  # the next start makes a fork server of this environment
    monkeypatch.setattr(os, "environ", {"PATH": os.environ["PATH"], "SPT_NOENV": "1"})
    process, output = _start(tmp_path, "sleep", "30")
    try:
        _wait_for_output(process, output)
        title = Path(f"/proc/{process.pid}/cmdline").read_bytes().rstrip(b"\0")
        assert title.endswith(b"sleep 30 " + b"x" * 2000)
    finally:
        process.terminate()
        process.wait(10)
        forkserver.close_all()


@pytest.mark.parametrize(
    "argv, status, said",
    [
        (["return", "0"], 0, ""),
        (["return", "3"], 3, ""),
        (["exit", "3"], 3, ""),  # as a replay server refusing its folder
        (["exit", "0"], 0, ""),
        (["exit-message", "no such table"], 1, "no such table"),
        (["raise", "boom"], 1, "RuntimeError: boom"),
    ],
)
def test_exit_statuses_and_messages_are_a_plain_processs(tmp_path, mode, argv, status, said):
    process, output = _start(tmp_path, *argv)
    assert process.wait(30) == status and process.poll() == status
    assert said in output.read_text()


def test_kill_wait_timeout_and_signals_after_the_end(tmp_path, mode):
    process, _ = _start(tmp_path, "sleep", "30")
    with pytest.raises(subprocess.TimeoutExpired):
        process.wait(0.1)
    process.kill()
    assert process.wait(10) == -signal.SIGKILL
    process.terminate()  # ended: nothing to signal, no error


def test_a_dead_fork_server_is_replaced_and_its_running_process_waited_for(tmp_path):
    first, _ = _start(tmp_path, "sleep", "30")
    server = _ppid(first.pid)
    assert server != os.getpid()
    os.kill(server, signal.SIGKILL)
    time.sleep(0.5)
    assert first.poll() is None  # it runs on without its fork server
    second, _ = _start(tmp_path, "sleep", "30")
    assert _ppid(second.pid) not in (server, os.getpid())  # a new fork server's
    second.terminate()
    assert second.wait(10) == -signal.SIGTERM
    first.terminate()
    assert first.wait(10) == -signal.SIGKILL  # its status died with its server: reported so
