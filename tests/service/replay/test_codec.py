"""The columnar msgpack codec round-trips arrays and refuses malformed payloads."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from service.replay.codec import CodecError, decode_batch, encode_batch


def test_round_trip_keeps_dtype_shape_and_values():
    batch = {
        "obs": np.random.default_rng(0).normal(size=(5, 2, 3)).astype(np.float32),
        "done": np.array([True, False, True, False, False]),
        "version": np.arange(5, dtype=np.int64),
        "empty": np.zeros((5, 0), dtype=np.float64),
    }
    decoded = decode_batch(encode_batch(batch))
    assert decoded.keys() == batch.keys()
    for name, array in batch.items():
        assert decoded[name].dtype == array.dtype
        np.testing.assert_array_equal(decoded[name], array)


def _payload(columns) -> bytes:
    return msgpack.packb({"columns": columns}, use_bin_type=True)


GOOD = {"dtype": "<f4", "shape": [2], "data": np.zeros(2, np.float32).tobytes()}


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"\xc1garbage", "not valid msgpack"),
        (b"", "not valid msgpack"),
        (msgpack.packb([1, 2, 3]), "single key 'columns'"),
        (_payload({}), "non-empty map"),
        (_payload({"x": {**GOOD, "dtype": "|O"}}), "dtype '|O'"),
        (_payload({"x": {**GOOD, "dtype": "<U4"}}), "dtype '<U4'"),
        (_payload({"x": {**GOOD, "shape": [3]}}), "need 12"),
        (_payload({"x": {**GOOD, "shape": [-2]}}), "non-negative integers"),
        (_payload({"x": {**GOOD, "shape": []}}), "1 to 8"),
        (_payload({"x": {**GOOD, "data": "text"}}), "data must be bytes"),
        (_payload({"x": {"dtype": "<f4", "shape": [2]}}), "keys dtype, shape, data"),
        (_payload({7: GOOD}), "not valid msgpack"),  # integer map keys are refused
        (msgpack.packb({"columns": {"x": msgpack.ExtType(1, b"evil")}}), "ext type"),
    ],
)
def test_malformed_payloads_are_refused_with_a_reason(payload, message):
    with pytest.raises(CodecError, match=message.replace("(", r"\(").replace("|", r"\|")):
        decode_batch(payload)


def test_payload_over_the_size_limit_is_refused():
    payload = encode_batch({"x": np.zeros(1000, np.float32)})
    with pytest.raises(CodecError, match="limit is 100"):
        decode_batch(payload, max_bytes=100)
