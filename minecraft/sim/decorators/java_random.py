"""Java's ``java.util.Random``: the 48-bit linear congruential generator Malmo's maze and
classroom generators draw from, so that a mission's seed draws the numbers it draws in
Java (the generators then make the same choices in the same order)."""

from __future__ import annotations

import math
from typing import Optional

_MULT = 0x5DEECE66D
_MASK = (1 << 48) - 1


def _int32(v: int) -> int:
    v &= 0xFFFFFFFF
    return v - (1 << 32) if v >= 1 << 31 else v


class JavaRandom:
    """``new java.util.Random(seed)``.

    Args:
        seed: any integer (Java's ``long``; wrapped to 64 bits as Java would).
    """

    def __init__(self, seed: int) -> None:
        self._seed = (seed ^ _MULT) & _MASK
        self._gaussian: Optional[float] = None

    def _next(self, bits: int) -> int:
        self._seed = (self._seed * _MULT + 0xB) & _MASK
        return _int32(self._seed >> (48 - bits))

    def next_int(self, bound: Optional[int] = None) -> int:
        """``nextInt()`` (any int) or ``nextInt(bound)`` (in [0, bound)).

        Raises:
            ValueError: ``bound`` is not positive.
        """
        if bound is None:
            return self._next(32)
        if bound <= 0:
            raise ValueError("bound must be positive")
        if bound & -bound == bound:  # a power of two: the high bits
            return (bound * self._next(31)) >> 31
        while True:
            bits = self._next(31)
            val = bits % bound
            if bits - val + (bound - 1) < 1 << 31:  # Java's int overflow check
                return val

    def next_float(self) -> float:
        """``nextFloat()``: 24 random bits in [0, 1)."""
        return self._next(24) / float(1 << 24)

    def next_double(self) -> float:
        """``nextDouble()``: 53 random bits in [0, 1)."""
        return ((self._next(26) << 27) + self._next(27)) * (1.0 / (1 << 53))

    def next_gaussian(self) -> float:
        """``nextGaussian()``: Marsaglia's polar method, the second value kept."""
        if self._gaussian is not None:
            g, self._gaussian = self._gaussian, None
            return g
        while True:
            v1 = 2 * self.next_double() - 1
            v2 = 2 * self.next_double() - 1
            s = v1 * v1 + v2 * v2
            if 0 < s < 1:
                break
        m = math.sqrt(-2 * math.log(s) / s)  # Java's StrictMath.log/sqrt
        self._gaussian = v2 * m
        return v1 * m
