"""Starting a local Ray instance again when its first start fails under load."""

from __future__ import annotations

import pytest
from ray.exceptions import RaySystemError

from service.run.orchestration.ray_session import start_retrying

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
