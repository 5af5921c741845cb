"""Fuzzing: 10,000+ generated malformed payloads against a real server process.

Every payload is malformed by construction (random bytes, random msgpack values,
truncations, or a valid batch with exactly one injected defect). The server must
answer each with INVALID_ARGUMENT or RESOURCE_EXHAUSTED, never crash, and keep its
stored data bit-for-bit.
"""

from __future__ import annotations

import grpc
import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch
from service.run.replay_host.process import ReplayProcess
from tests.service.replay.helpers import SCALAR_SIGNATURE, read_all, scalar_batch

pytestmark = pytest.mark.service  # a real server process per module

TABLE = [{"name": "t", "max_size": 1000, "sampler": "fifo", "signature": SCALAR_SIGNATURE}]
EXAMPLES_PER_STRATEGY = 2_600  # four strategies: 10,400 payloads in all

VALID = {
    "x": {"dtype": "<i8", "shape": [2], "data": np.arange(2, dtype=np.int64).tobytes()},
    "terminated": {"dtype": "|b1", "shape": [2], "data": bytes(2)},
    "truncated": {"dtype": "|b1", "shape": [2], "data": bytes(2)},
}


def defects() -> st.SearchStrategy[dict]:
    """A valid columnar map with exactly one thing wrong."""
    column = st.sampled_from(sorted(VALID))
    return st.one_of(
        column.map(lambda c: {**VALID, c: {**VALID[c], "dtype": "|O"}}),
        st.tuples(column, st.sampled_from(["<f4", "<i4", "|u1", "<f8", "<U1", "xyz", ""])).map(
            lambda cd: (
                {**VALID, cd[0]: {**VALID[cd[0]], "dtype": cd[1]}}
                if cd[1] != VALID[cd[0]]["dtype"]
                else {**VALID, cd[0]: {**VALID[cd[0]], "dtype": "|O"}}
            )
        ),
        st.tuples(column, st.lists(st.integers(-3, 5), max_size=4)).map(
            lambda cs: (
                {**VALID, cs[0]: {**VALID[cs[0]], "shape": cs[1]}}
                if cs[1] != [2]
                else {**VALID, cs[0]: {**VALID[cs[0]], "shape": [3]}}
            )
        ),
        st.tuples(column, st.integers(0, 15)).map(  # truncated data
            lambda ci: (
                {**VALID, ci[0]: {**VALID[ci[0]], "data": VALID[ci[0]]["data"][: ci[1]]}}
                if ci[1] < len(VALID[ci[0]]["data"])
                else {**VALID, ci[0]: {**VALID[ci[0]], "data": b""}}
            )
        ),
        column.map(lambda c: {k: v for k, v in VALID.items() if k != c}),  # missing column
        st.text(min_size=1, max_size=8).map(  # unknown column
            lambda name: {**VALID, "zz" + name: VALID["x"]}
        ),
        column.map(lambda c: {**VALID, c: msgpack.ExtType(3, b"x")}),
        column.map(lambda c: {**VALID, c: {**VALID[c], "extra": 1}}),
        st.just({**VALID, "x": {**VALID["x"], "data": "text"}}),
    )


msgpack_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**63), 2**64 - 1)
    | st.floats()
    | st.text()
    | st.binary(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(), inner, max_size=4),
    max_leaves=12,
)


@pytest.fixture(scope="module")
def server():
    with ReplayProcess(TABLE) as process:
        client = ReplayClient(process.address, max_retries=0)
        client.insert("t", scalar_batch(range(50)))
        yield process, client
        client.close()


def send(client: ReplayClient, payload: bytes) -> None:
    request = replay_pb2.InsertRequest(table="t", batch=payload)
    with pytest.raises(grpc.RpcError) as caught:
        client.stub.Insert(iter([request]))
    assert caught.value.code() in (
        grpc.StatusCode.INVALID_ARGUMENT,
        grpc.StatusCode.RESOURCE_EXHAUSTED,
    ), caught.value.details()


FUZZ = settings(
    max_examples=EXAMPLES_PER_STRATEGY,
    deadline=None,
    derandomize=True,  # the same 10,400 payloads every run
    suppress_health_check=list(HealthCheck),
    database=None,
)


@FUZZ
@given(st.binary(max_size=256))
def test_random_bytes(server, payload):
    send(server[1], payload)


@FUZZ
@given(msgpack_values)
def test_random_msgpack_values(server, value):
    send(server[1], msgpack.packb(value, use_bin_type=True))


@FUZZ
@given(defects())
def test_one_defect_in_a_valid_batch(server, columns):
    send(server[1], msgpack.packb({"columns": columns}, use_bin_type=True))


VALID_PAYLOAD = encode_batch(scalar_batch([7, 8, 9]))


@FUZZ
@given(st.integers(0, len(VALID_PAYLOAD) - 1))
def test_truncated_valid_payload(server, cut):
    send(server[1], VALID_PAYLOAD[:cut])


def test_server_survived_and_data_is_unchanged(server):
    """Runs after the fuzzers (file order): the 50 stored items are intact."""
    process, client = server
    assert process.process.poll() is None, "the server process died"
    np.testing.assert_array_equal(read_all(client, "t"), np.arange(50))
    assert client.info()[0].inserts == 50
