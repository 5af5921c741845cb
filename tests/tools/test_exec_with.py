"""tests/tools/exec_with.py: a process setting applied to the command it execs, and no test
or source file using ``preexec_fn`` in its place (the fork it forces can abort under gRPC)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tools.exec_with import command as exec_with

ROOT = Path(__file__).resolve().parents[2]
SHOW_LIMITS = (
    "import resource, signal; print(resource.getrlimit(resource.RLIMIT_FSIZE)[0],"
    " signal.getsignal(signal.SIGINT) is signal.default_int_handler)"
)


IGNORING_CTRL_C = [  # as a shell starts a background job: SIGINT ignored, kept across exec
    sys.executable, "-c",
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN);"
    " os.execv(sys.argv[1], sys.argv[1:])",
]  # fmt: skip


def _shown(argv: list[str]) -> list[str]:
    return subprocess.run(
        [*argv, sys.executable, "-c", SHOW_LIMITS], cwd=ROOT, capture_output=True, text=True,
        check=True,
    ).stdout.split()  # fmt: skip


@pytest.mark.service
def test_the_limit_and_ctrl_c_reach_the_command_it_runs():
    assert _shown(exec_with("--file-size-limit", "65536"))[0] == "65536"
    assert _shown(IGNORING_CTRL_C)[1] == "False"  # Python then never raises KeyboardInterrupt
    assert _shown([*IGNORING_CTRL_C, *exec_with("--default-sigint")])[1] == "True"


def test_no_python_file_forks_through_preexec_fn():
    here = Path(__file__).name
    uses = [
        str(path.relative_to(ROOT))
        for folder in ("actors", "bench", "learner", "service", "tests", "examples", "deploy")
        for path in (ROOT / folder).rglob("*.py")
        if path.name != here and re.search(r"preexec_fn\s*=", path.read_text())
    ]
    assert not uses, f"use tests/tools/exec_with.py (or a wrapper like it) instead: {uses}"
