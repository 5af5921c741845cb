"""Columnar msgpack batches: the payload format of the replay wire contract.

A batch is ``{"columns": {name: {"dtype": "<f4", "shape": [n, ...], "data": bytes}}}``.
Decoding never unpickles and refuses msgpack ext types, so a hostile payload can
at worst be rejected, never executed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import msgpack
import numpy as np

# Only plain numeric dtypes cross the wire: no objects, no strings, no void.
ALLOWED_DTYPES = frozenset(
    np.dtype(d).str
    for d in ("bool", "u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f2", "f4", "f8")
)
MAX_COLUMNS = 64
MAX_NDIM = 8
DEFAULT_MAX_BYTES = 64 * 1024 * 1024

Batch = dict[str, np.ndarray]

TOKEN_METADATA_KEY = "graft-token"
"""gRPC call metadata key that carries the access token (client and server agree on it)."""


class CodecError(ValueError):
    """A payload is malformed; the message names the field and the limit."""


class PayloadTooLarge(CodecError):
    """A payload exceeds the configured size limit."""


def encode_batch(columns: Mapping[str, np.ndarray]) -> bytes:
    """Packs columns (all sharing their leading dimension) into one payload."""
    packed = {}
    for name, array in columns.items():
        array = np.ascontiguousarray(array)
        packed[name] = {
            "dtype": array.dtype.str,
            "shape": list(array.shape),
            "data": array.data if array.size else b"",
        }
    payload: bytes = msgpack.packb({"columns": packed}, use_bin_type=True)
    return payload


def stack_batches(batches: list[Batch]) -> Batch:
    """Several batches of equal size as one, batch i in rows [i * n, (i + 1) * n): what a
    sample response carrying `num_batches` > 1 holds (`split_batch` undoes it)."""
    if len(batches) == 1:
        return batches[0]
    return {name: np.concatenate([b[name] for b in batches]) for name in batches[0]}


def split_batch(batch: Batch, count: int) -> list[Batch]:
    """The `count` equal batches stacked in `batch` (views, no copies).

    Raises:
        CodecError: a column's length is not a multiple of `count`, or columns differ in
            length.
    """
    if count == 1:
        return [batch]
    lengths = {len(a) for a in batch.values()}
    if count < 1 or len(lengths) != 1 or next(iter(lengths)) % count:
        raise CodecError(
            f"a response of {count} stacked batches has columns of {sorted(lengths)} items; "
            f"each must be a multiple of {count}, all equal"
        )
    n = next(iter(lengths)) // count
    return [{name: a[i * n : (i + 1) * n] for name, a in batch.items()} for i in range(count)]


def _refuse_ext(code: int, data: bytes) -> None:
    raise CodecError(f"msgpack ext type {code} is not allowed")


def decode_batch(payload: bytes, *, max_bytes: int = DEFAULT_MAX_BYTES) -> Batch:
    """Unpacks a payload into numpy columns, checking every size before trusting it.

    Raises:
        CodecError: the payload is not a well-formed columnar batch.
    """
    if len(payload) > max_bytes:
        raise PayloadTooLarge(f"payload is {len(payload)} bytes, limit is {max_bytes}")
    try:
        message = msgpack.unpackb(
            payload,
            raw=False,
            use_list=True,
            strict_map_key=True,
            ext_hook=_refuse_ext,
            max_bin_len=max_bytes,
            max_str_len=1024,
            max_array_len=MAX_NDIM,
            max_map_len=MAX_COLUMNS,
        )
    except CodecError:
        raise
    except Exception as error:  # msgpack raises several unrelated types on garbage
        raise CodecError(f"payload is not valid msgpack: {error}") from None
    if not isinstance(message, dict) or set(message) != {"columns"}:
        raise CodecError("payload must be a map with the single key 'columns'")
    columns = message["columns"]
    if not isinstance(columns, dict) or not columns:
        raise CodecError("'columns' must be a non-empty map of column name to array")
    return {name: _decode_column(name, spec) for name, spec in columns.items()}


def _decode_column(name: object, spec: object) -> np.ndarray:
    if not isinstance(name, str) or not name:
        raise CodecError(f"column name {name!r} must be a non-empty string")
    if not isinstance(spec, dict) or set(spec) != {"dtype", "shape", "data"}:
        raise CodecError(f"column '{name}' must be a map with keys dtype, shape, data")
    dtype, shape, data = spec["dtype"], spec["shape"], spec["data"]
    if not isinstance(dtype, str) or dtype not in ALLOWED_DTYPES:
        raise CodecError(f"column '{name}' has dtype {dtype!r}; allowed: {sorted(ALLOWED_DTYPES)}")
    if (
        not isinstance(shape, list)
        or not 1 <= len(shape) <= MAX_NDIM
        or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape)
    ):
        raise CodecError(
            f"column '{name}' shape {shape!r} must be 1 to {MAX_NDIM} non-negative integers"
        )
    if not isinstance(data, bytes):
        raise CodecError(f"column '{name}' data must be bytes")
    expected = math.prod(shape) * np.dtype(dtype).itemsize
    if len(data) != expected:
        raise CodecError(
            f"column '{name}' has {len(data)} data bytes, dtype {dtype} and shape "
            f"{tuple(shape)} need {expected}"
        )
    array = np.frombuffer(data, dtype=dtype).reshape(shape)
    if array.dtype == np.bool_ and array.size:
        highest = int(array.view(np.uint8).max())
        if highest > 1:
            raise CodecError(
                f"column '{name}' is bool but holds byte {highest:#04x}; booleans are 0 or 1"
            )
    return array
