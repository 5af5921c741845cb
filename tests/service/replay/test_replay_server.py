"""Insert and sample against a real replay server process; bad input leaves data intact."""

from __future__ import annotations

import grpc
import numpy as np
import pytest

from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch
from service.replay.errors import InvalidArgument, TableNotFound
from service.replay.server.grpc_server import InsecureBindError, ServerOptions, build_server
from service.replay.server.store import ReplayCore
from service.replay.server.table_config import make_table
from tests.conftest import PENDULUM_SIGNATURE, pendulum_batch


def assert_rows_are_the_inserted_ones(batch):
    """Every sampled row must equal the row inserted under its index (obs[:, 0])."""
    i = batch["obs"][:, 0].astype(np.int64)
    expected = pendulum_batch(int(i.max()) + 1)
    for name in PENDULUM_SIGNATURE:
        np.testing.assert_array_equal(batch[name], expected[name][i], err_msg=name)


def test_insert_then_sample_returns_stored_rows(replay_client: ReplayClient):
    assert replay_client.insert("transitions", pendulum_batch(300)) == 300
    batch = replay_client.sample("transitions", 64)
    assert batch["obs"].shape == (64, 3)
    assert_rows_are_the_inserted_ones(batch)
    assert set(batch["_key"].tolist()) <= set(range(300))
    np.testing.assert_allclose(batch["_probability"], 1 / 300)
    [table] = replay_client.info()
    assert (table.size, table.inserts, table.samples) == (300, 300, 64)


def test_fifo_eviction_keeps_the_newest_max_size_items(replay_client: ReplayClient):
    replay_client.insert("transitions", pendulum_batch(700))
    replay_client.insert("transitions", pendulum_batch(700, start=700))
    [table] = replay_client.info()
    assert table.size == 1000
    keys = replay_client.sample("transitions", 2000)["_key"]
    assert keys.min() >= 400  # the 400 oldest were evicted


def test_sample_stream_prefetches_batches(replay_client: ReplayClient):
    replay_client.insert("transitions", pendulum_batch(500))
    stream = replay_client.sample_stream("transitions", 32, prefetch=2)
    batches = [next(stream) for _ in range(10)]
    stream.close()
    assert all(b["obs"].shape == (32, 3) for b in batches)
    assert stream.table_inserts == 500


def _raw_insert(client: ReplayClient, table: str, payload: bytes):
    request = replay_pb2.InsertRequest(table=table, batch=payload)
    return client.stub.Insert(iter([request]))


BAD = {
    "garbage bytes": (b"\x00\xffnot msgpack", "not valid msgpack"),
    "wrong shape": (
        encode_batch({**pendulum_batch(4), "obs": np.zeros((4, 4), np.float32)}),
        "column 'obs' has shape (4, 4), table expects (4, 3)",
    ),
    "wrong dtype": (
        encode_batch({**pendulum_batch(4), "reward": np.zeros(4, np.float64)}),
        "column 'reward' has dtype <f8, table expects <f4",
    ),
    "unknown column": (
        encode_batch({**pendulum_batch(4), "color": np.zeros(4, np.float32)}),
        "unknown column(s) ['color']",
    ),
    "missing column": (
        encode_batch({k: v for k, v in pendulum_batch(4).items() if k != "reward"}),
        "missing column(s) ['reward']",
    ),
    "NaN": (
        encode_batch({**pendulum_batch(4), "reward": np.array([0, np.nan, 0, 0], np.float32)}),
        "column 'reward' contains NaN or Inf",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_gets_invalid_argument_and_changes_nothing(replay_client, case):
    replay_client.insert("transitions", pendulum_batch(100))
    before = replay_client.info()[0]
    payload, message = BAD[case]
    with pytest.raises(grpc.RpcError) as caught:
        _raw_insert(replay_client, "transitions", payload)
    assert caught.value.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert message in caught.value.details()
    after = replay_client.info()[0]
    assert (after.size, after.inserts) == (before.size, before.inserts)
    # The server keeps serving, and what it serves is still exactly what was stored.
    assert_rows_are_the_inserted_ones(replay_client.sample("transitions", 256))
    assert replay_client.insert("transitions", pendulum_batch(10, start=100)) == 10


def test_typed_client_errors(replay_client: ReplayClient):
    with pytest.raises(TableNotFound, match="no table named 'nope'"):
        replay_client.insert("nope", pendulum_batch(2))
    with pytest.raises(InvalidArgument, match="missing column"):
        replay_client.insert("transitions", {"obs": np.zeros((2, 3), np.float32)})


def test_resent_batch_is_stored_once(replay_client: ReplayClient):
    """A writer resending a batch (lost acknowledgement) does not double it."""
    request = replay_pb2.InsertRequest(
        table="transitions", batch=encode_batch(pendulum_batch(5)), writer_id="w", sequence=1
    )
    first = replay_client.stub.Insert(iter([request]))
    again = replay_client.stub.Insert(iter([request]))
    assert (first.items_inserted, again.items_inserted) == (5, 0)
    assert again.batches_dropped_as_duplicates == 1
    assert again.acked_sequence["w"] == 1
    assert replay_client.info()[0].size == 5


def test_non_loopback_bind_without_token_is_refused():
    core = ReplayCore([make_table({"name": "t", "max_size": 10, "signature": PENDULUM_SIGNATURE})])
    with pytest.raises(InsecureBindError, match="needs a shared token"):
        build_server(core, ServerOptions(host="0.0.0.0"))


def test_token_is_required_when_configured():
    core = ReplayCore([make_table({"name": "t", "max_size": 10, "signature": PENDULUM_SIGNATURE})])
    running = build_server(core, ServerOptions(token="s3cret"))
    server, port = running.server, running.port
    try:
        from service.replay.errors import Unauthenticated

        with pytest.raises(Unauthenticated):
            ReplayClient(f"127.0.0.1:{port}", max_retries=0).info()
        with pytest.raises(Unauthenticated):
            ReplayClient(f"127.0.0.1:{port}", token="wrong", max_retries=0).info()
        assert ReplayClient(f"127.0.0.1:{port}", token="s3cret").info()[0].name == "t"
    finally:
        server.stop(0)


def test_client_pickles_as_its_address_and_settings():
    import pickle

    client = ReplayClient("127.0.0.1:1", token="t", max_retries=3, tls_root_cert="/ca.pem")
    copy = pickle.loads(pickle.dumps(client))
    assert (copy.address, copy.token, copy.max_retries, copy.tls_root_cert) == (
        "127.0.0.1:1",
        "t",
        3,
        "/ca.pem",
    )
    assert copy.writer_id != client.writer_id  # each copy numbers its own batches


def test_stream_wait_can_time_out(replay_client: ReplayClient):
    stream = replay_client.sample_stream("transitions", 4, prefetch=1)  # table is empty
    with pytest.raises(TimeoutError, match="no sampled batch within 0.2 s"):
        stream.next_within(0.2)
    replay_client.insert("transitions", pendulum_batch(10))
    assert stream.next_within(10)["obs"].shape == (4, 3)
    stream.close()
