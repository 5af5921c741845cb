"""Seeded generators of malformed insert payloads, for the fuzz tests.

Each generator is a plain function of a `random.Random`: the same seed gives the same
payloads on every run and machine, and a failure names the seed and index that reproduce
it. Values lean towards the edges a decoder gets wrong (empty and one-byte inputs, integer
and float limits, NaN, astral and control characters, nesting), as a property-based
generator's do, at a few microseconds a value (hypothesis took about 2 ms, most of the
fuzz tests' CPU).
"""

from __future__ import annotations

import random
import string
import sys
from typing import Any

import msgpack
import numpy as np

VALID = {
    "x": {"dtype": "<i8", "shape": [2], "data": np.arange(2, dtype=np.int64).tobytes()},
    "terminated": {"dtype": "|b1", "shape": [2], "data": bytes(2)},
    "truncated": {"dtype": "|b1", "shape": [2], "data": bytes(2)},
}
"""A valid columnar map of the scalar signature: two rows."""
COLUMNS = sorted(VALID)
WRONG_DTYPES = ["<f4", "<i4", "|u1", "<f8", "<U1", "xyz", "", "|O"]

INTEGERS = [
    0, 1, -1, 2, 127, 128, 255, 256, -32, -33, 2**15, 2**16, 2**31 - 1, 2**31, -(2**31),
    2**32, 2**53, 2**63 - 1, 2**63, -(2**63), 2**64 - 1,
]  # fmt: skip
"""Where msgpack's integer encodings change width, and the ends of its range."""
FLOATS = [
    0.0, -0.0, 1.0, -1.5, float("nan"), float("inf"), float("-inf"), 5e-324,
    sys.float_info.max, sys.float_info.min, 1e16, 2.0**53 + 1,
]  # fmt: skip
CHARACTERS = [
    string.printable, "\x00\x01\x1f\x7f\u0085\u2028", "éßø中文ひら", "\U0001f600\U00010000"
]  # fmt: skip
"""Pools of characters text draws most of its characters from."""
MSGPACK_PREFIXES = bytes(
    [0x80, 0x81, 0x8F, 0x90, 0x9F, 0xA0, 0xBF, 0xC0, 0xC1, 0xC2, 0xC4, 0xC5, 0xC6, 0xC7]
    + [0xCA, 0xCB, 0xCF, 0xD3, 0xD4, 0xD9, 0xDA, 0xDB, 0xDC, 0xDD, 0xDE, 0xDF, 0xFF]
)
"""First bytes that open a msgpack map, array, string, binary, extension or number, and
0xC1, which msgpack never uses."""


def random_bytes(rng: random.Random, max_size: int = 256) -> bytes:
    """Up to `max_size` bytes: mostly short, half of them opening like a msgpack value."""
    size = rng.choice([0, 1, 2, 3, 5, 8]) if rng.random() < 0.3 else rng.randint(0, max_size)
    data = rng.randbytes(size)
    if data and rng.random() < 0.5:
        data = bytes([rng.choice(MSGPACK_PREFIXES)]) + data[1:]
    return data


def text(rng: random.Random, max_size: int = 12) -> str:
    """Unicode text: ASCII, control characters, and code points of every plane (no lone
    surrogates: msgpack cannot encode them)."""
    out = []
    for _ in range(rng.randint(0, max_size)):
        if rng.random() < 0.2:
            code = rng.randint(0x80, 0x10FFFF)
            out.append(chr(code) if not 0xD800 <= code <= 0xDFFF else "\ufffd")
        else:
            out.append(rng.choice(rng.choice(CHARACTERS)))
    return "".join(out)


def _leaf(rng: random.Random) -> Any:
    kind = rng.randrange(6)
    if kind == 0:
        return None
    if kind == 1:
        return rng.random() < 0.5
    if kind == 2:
        if rng.random() < 0.5:
            return rng.choice(INTEGERS)
        return rng.randint(-(2**63), 2**64 - 1) >> rng.randrange(64)
    if kind == 3:
        return rng.choice(FLOATS) if rng.random() < 0.5 else rng.uniform(-1e6, 1e6)
    if kind == 4:
        return text(rng)
    return rng.randbytes(rng.randint(0, 16))


def msgpack_value(rng: random.Random, leaves: int = 12) -> Any:
    """A value msgpack can encode: a leaf, or lists and string-keyed maps of up to four
    entries nested around at most `leaves` leaves."""
    budget = [rng.randint(1, leaves)]

    def value(depth: int) -> Any:
        if budget[0] <= 1 or depth > 4 or rng.random() < 0.4:
            budget[0] -= 1
            return _leaf(rng)
        size = rng.randint(0, 4)
        if rng.random() < 0.5:
            return [value(depth + 1) for _ in range(size)]
        return {text(rng, 6): value(depth + 1) for _ in range(size)}

    return value(0)


def one_defect(rng: random.Random) -> dict[str, Any]:
    """`VALID` with exactly one thing wrong in one column, or one column missing or extra."""
    column = rng.choice(COLUMNS)
    spec = VALID[column]
    kind = rng.randrange(8)
    if kind == 0:  # a dtype other than the column's
        dtype = rng.choice([d for d in WRONG_DTYPES if d != spec["dtype"]])
        return {**VALID, column: {**spec, "dtype": dtype}}
    if kind == 1:  # a shape other than [2]
        shape = [rng.randint(-3, 5) for _ in range(rng.randint(0, 4))]
        return {**VALID, column: {**spec, "shape": shape if shape != [2] else [3]}}
    if kind == 2:  # data cut short
        return {**VALID, column: {**spec, "data": spec["data"][: rng.randrange(len(spec["data"]))]}}
    if kind == 3:  # a column missing
        return {name: v for name, v in VALID.items() if name != column}
    if kind == 4:  # a column the table does not have
        return {**VALID, "zz" + text(rng, 8): VALID["x"]}
    if kind == 5:  # a column that is an extension value, not a map
        return {**VALID, column: msgpack.ExtType(rng.randrange(128), rng.randbytes(2))}
    if kind == 6:  # a field the codec does not know
        return {**VALID, column: {**spec, "zz" + text(rng, 6): _leaf(rng)}}
    return {**VALID, column: {**spec, "data": text(rng, 8)}}  # data as text, not bytes
