"""Java's ``java.util.Random``, which Malmo's maze and classroom generators draw from: the
same seed gives the numbers Java gives. The unbounded values are the ones a JVM prints
(often quoted); the bounded ones follow from them by ``Random.nextInt(int)``'s documented
arithmetic, worked by hand in the comments."""

from __future__ import annotations

import pytest

from minecraft.sim.decorators.java_random import JavaRandom


def test_next_int_matches_java() -> None:
    r = JavaRandom(42)
    assert [r.next_int(), r.next_int()] == [-1170105035, 234785527]
    assert JavaRandom(0).next_int() == -1155484576


def test_bounded_draws_match_java() -> None:
    assert JavaRandom(42).next_int(10) == 0  # next(31) = 1562431130, % 10
    assert JavaRandom(42).next_int(16) == 11  # a power of two: (16 * 1562431130) >> 31
    assert JavaRandom(42).next_double() == pytest.approx(0.7275636800328681, abs=1e-16)
    assert JavaRandom(0).next_double() == pytest.approx(0.730967787376657, abs=1e-16)
    assert JavaRandom(0).next_gaussian() == pytest.approx(0.8025330637390305, abs=1e-15)


def test_bound_must_be_positive() -> None:
    with pytest.raises(ValueError, match="bound must be positive"):
        JavaRandom(1).next_int(0)
