"""bench/travel.py's comparison of a controller with the tree, on hand-made episode rows."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "bench_travel", Path(__file__).resolve().parents[2] / "bench" / "travel.py"
)
travel = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(travel)


def _row(mission: int, arrived: bool, ticks: int) -> dict:
    return {"mission": mission, "arrived": arrived, "ticks": ticks}


def test_paired_speed_counts_only_missions_both_reached() -> None:
    tree = [_row(0, True, 100), _row(1, True, 200), _row(2, False, 600), _row(3, True, 50)]
    other = [_row(0, True, 80), _row(1, True, 220), _row(2, True, 90), _row(3, True, 50)]
    p = travel.paired_speed(tree, other)
    # Missions 0, 1, 3: ratios 0.8, 1.1, 1.0 (mission 2: the tree never arrived).
    assert p["both"] == 3 and p["ratio"] == pytest.approx(1.0)
    assert (p["faster"], p["slower"]) == (1, 1)


def test_sign_test_by_hand() -> None:
    # 9 of 10 one way: 2 * (C(10,0) + C(10,1)) / 2^10 = 22 / 1024.
    assert travel.sign_test(9, 1) == pytest.approx(22 / 1024)
    assert travel.sign_test(1, 9) == travel.sign_test(9, 1)
    assert travel.sign_test(5, 5) == 1.0 and travel.sign_test(0, 0) == 1.0
