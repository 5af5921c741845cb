"""Scripts in bench/ run as `python bench/NAME.py`, which puts bench/ first on sys.path: a
script named like an importable module (graft's `learner`, or a dependency) would hide it
from every other script there."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parents[2] / "bench"


def test_no_bench_script_hides_a_module_the_others_import() -> None:
    names = sorted(p.stem for p in BENCH.glob("*.py") if p.stem != "__init__")
    assert "pendulum" in names and "replay" in names  # the scripts `make bench` runs
    hidden = [name for name in names if importlib.util.find_spec(name) is not None]
    assert not hidden, f"bench/ scripts named like importable modules: {hidden}"
