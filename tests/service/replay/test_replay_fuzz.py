"""Fuzzing: 10,000+ generated malformed payloads against a real server process.

Every payload is malformed by construction (random bytes, random msgpack values, a valid
batch with exactly one injected defect, or every truncation of a valid payload). The server
must answer each with INVALID_ARGUMENT or RESOURCE_EXHAUSTED, never crash, and keep its
stored data bit-for-bit. The payloads come from seeded generators (`malformed.py`): the
same ones every run.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterable

import grpc
import msgpack
import numpy as np
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch
from tests.service.replay import malformed
from tests.service.replay.helpers import SCALAR_SIGNATURE, read_all, scalar_batch

pytestmark = pytest.mark.service  # a real server process per module

TABLE = [{"name": "t", "max_size": 1000, "sampler": "fifo", "signature": SCALAR_SIGNATURE}]
EXAMPLES_PER_GENERATOR = 3_300  # three generators and 141 truncations: 10,041 payloads
SEED = 2600


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


def send_all(client: ReplayClient, payloads: Iterable[bytes]) -> int:
    """Sends each payload; a failure names the payload's index and bytes."""
    sent = 0
    for index, payload in enumerate(payloads):
        try:
            send(client, payload)
        except BaseException as error:
            raise AssertionError(f"payload {index} ({payload[:80]!r}): {error}") from error
        sent += 1
    return sent


def generated(make: Callable[[random.Random], bytes]) -> Iterable[bytes]:
    rng = random.Random(SEED)
    return (make(rng) for _ in range(EXAMPLES_PER_GENERATOR))


def test_random_bytes(server):
    assert send_all(server[1], generated(malformed.random_bytes)) == EXAMPLES_PER_GENERATOR


def test_random_msgpack_values(server):
    def packed(rng: random.Random) -> bytes:
        return msgpack.packb(malformed.msgpack_value(rng), use_bin_type=True)

    assert send_all(server[1], generated(packed)) == EXAMPLES_PER_GENERATOR


def test_one_defect_in_a_valid_batch(server):
    def packed(rng: random.Random) -> bytes:
        return msgpack.packb({"columns": malformed.one_defect(rng)}, use_bin_type=True)

    assert send_all(server[1], generated(packed)) == EXAMPLES_PER_GENERATOR


VALID_PAYLOAD = encode_batch(scalar_batch([7, 8, 9]))


def test_truncated_valid_payload(server):
    cuts = [VALID_PAYLOAD[:cut] for cut in range(len(VALID_PAYLOAD))]
    assert send_all(server[1], cuts) == len(VALID_PAYLOAD) == 141


def test_server_survived_and_data_is_unchanged(server):
    """Runs after the fuzzers (file order): the 50 stored items are intact."""
    process, client = server
    assert process.process.poll() is None, "the server process died"
    np.testing.assert_array_equal(read_all(client, "t"), np.arange(50))
    assert client.info()[0].inserts == 50
