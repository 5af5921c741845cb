"""Starting a local Ray instance (again when its first start fails under load), without the
processes graft does not use."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import pytest
import ray
from ray._private import ray_constants
from ray.exceptions import RaySystemError

from graft.orchestration.ray_session import TASK_EVENTS_KEPT, start_retrying

GCS_DOWN = "System error: Failed to connect to GCS. Please check if the GCS server is running"


def _starts(failures: int) -> tuple[list[str], object]:
    """A start that fails `failures` times as Ray's driver does, recording each call."""
    calls: list[str] = []

    def start() -> None:
        calls.append("start")
        if calls.count("start") <= failures:
            raise RaySystemError(GCS_DOWN)

    return calls, start


def test_a_failed_start_is_stopped_and_tried_again_in_one_line(capsys) -> None:
    calls, start = _starts(failures=1)
    start_retrying(start, tries=3, stop=lambda: calls.append("stop"))
    assert calls == ["start", "stop", "start"]
    said = capsys.readouterr().err.strip()
    assert "\n" not in said and said.startswith("local Ray did not start (")
    assert "starting it again (2 of 3)" in said


def test_the_last_failure_is_raised_after_every_try_and_stopped(capsys) -> None:
    calls, start = _starts(failures=5)
    with pytest.raises(RaySystemError, match="Failed to connect to GCS"):
        start_retrying(start, tries=2, stop=lambda: calls.append("stop"))
    assert calls == ["start", "stop", "start", "stop"]


def test_other_errors_are_not_retried() -> None:
    def start() -> None:
        raise ValueError("a bad argument")

    with pytest.raises(ValueError):
        start_retrying(start, tries=3, stop=lambda: None)


def test_a_local_instance_runs_without_a_log_monitor_or_autoscaler(ray_local) -> None:
    # ray_local starts it as graft train does (start_local): no worker output reaches the
    # driver, so nothing tails the log files; nothing scales one machine; tasks still run.
    node = ray._private.worker._global_node
    live = {kind for kind, _ in node.live_processes()}
    assert ray_constants.PROCESS_TYPE_RAYLET in live
    assert ray_constants.PROCESS_TYPE_LOG_MONITOR not in live
    assert ray_constants.PROCESS_TYPE_MONITOR not in live
    monitor = "autoscaler/_private/monitor.py"
    assert _left_after(lambda: _children(lambda cmd: any(monitor in a for a in cmd)), 10.0) == set()
    assert ray.get(ray.remote(lambda: 7).remote()) == 7


def test_a_local_instance_keeps_no_idle_worker(ray_local) -> None:
    # Its workers are ended a second after their task (Ray keeps one per CPU by default,
    # each costing about 1 % of a core while it waits). The tasks get workers of their own
    # (a runtime environment no earlier task had), whose ends are watched: a worker an
    # earlier test left may still own objects or actors, and Ray keeps such a worker.
    fresh = ray.remote(lambda: os.getpid()).options(
        runtime_env={"env_vars": {"GRAFT_TEST_FRESH_WORKER": "1"}}
    )
    pids = set(ray.get([fresh.remote() for _ in range(2)]))
    still_idle = lambda: pids & _children(lambda cmd: cmd[:1] == ["ray::IDLE"])  # noqa: E731
    assert _left_after(still_idle, 30.0) == set()


def _children(matches: Callable[[list[str]], bool]) -> set[int]:
    """This process's live descendants whose command line `matches`."""
    import psutil  # Ray's vendored copy, importable once Ray is

    found = set()
    for child in psutil.Process().children(recursive=True):
        try:
            if child.status() != psutil.STATUS_ZOMBIE and matches(child.cmdline()):
                found.add(child.pid)
        except psutil.Error:
            pass
    return found


def _left_after(find: Callable[[], set[int]], wait_s: float) -> set[int]:
    """What `find()` still finds after up to `wait_s` (an ended process takes a moment)."""
    deadline = time.monotonic() + wait_s
    while (found := find()) and time.monotonic() < deadline:
        time.sleep(0.2)
    return found


def test_a_local_instances_gcs_keeps_a_bounded_history_of_task_events(ray_local) -> None:
    # Past TASK_EVENTS_KEPT actor calls the GCS overwrites its oldest task events (and says
    # so once in its log), where Ray's default keeps ten times as many, growing all the while.
    @ray.remote(num_cpus=0)
    class Echo:
        def call(self) -> int:
            return 1

    echo = Echo.remote()
    for _ in range(TASK_EVENTS_KEPT // 2000 + 2):
        assert sum(ray.get([echo.call.remote() for _ in range(2000)])) == 2000
    logs = Path(ray._private.worker._global_node.get_logs_dir_path())
    said = f"Max number of tasks event ({TASK_EVENTS_KEPT}) allowed is reached"
    found = lambda: any(said in f.read_text(errors="replace") for f in logs.glob("gcs_server*"))  # noqa: E731
    deadline = time.monotonic() + 30.0
    while not found():
        assert time.monotonic() < deadline, f"the GCS's log never said {said!r}"
        time.sleep(1.0)
    ray.kill(echo)
