"""Scripts in bench/ run as `python bench/NAME.py`, which puts bench/ first on sys.path: a
script named like an importable module (graft's `learner`, or a dependency) would hide it
from every other script there."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench"


@pytest.mark.service  # a fresh interpreter: pytest's own sys.path holds the tests' folders
def test_no_bench_script_hides_a_module_the_others_import() -> None:
    names = sorted(p.stem for p in BENCH.glob("*.py") if p.stem != "__init__")
    assert "pendulum" in names and "replay" in names  # the scripts `make bench` runs
    find = (
        "import importlib.util, json, sys; "
        "print(json.dumps([n for n in sys.argv[1:] if importlib.util.find_spec(n)]))"
    )
    with tempfile.TemporaryDirectory() as elsewhere:  # as a script sees it, bench/ aside
        found = subprocess.run(
            [sys.executable, "-c", find, *names],
            cwd=elsewhere,
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    hidden = json.loads(found)
    assert not hidden, f"bench/ scripts named like importable modules: {hidden}"
