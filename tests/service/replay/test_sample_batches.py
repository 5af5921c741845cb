"""Several batches per sample: a table draws them under one lock exactly as it would one
by one (each admitted and counted by the rate limiter), and a Sample response stacks
them without changing what a client receives."""

from __future__ import annotations

import numpy as np
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import CodecError, decode_batch, split_batch
from service.replay.server.rate_limiters import SampleToInsertRatio
from service.replay.server.samplers import make_sampler
from service.replay.server.signature import Signature
from service.replay.server.table import Table
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch

B = 8
SAMPLERS = {
    "uniform": {},
    "prioritized": {"sampler": make_sampler({"kind": "prioritized", "priority_exponent": 1.0})},
    "fifo": {"sampler": make_sampler("fifo")},
    "max_times_sampled": {"max_times_sampled": 1_000},  # drawn one by one: items may be used up
}


def ratio_table(case: str, **kwargs) -> Table:
    """4 samples per insert, sampling from 10 items on, 8 samples of slack."""
    limiter = SampleToInsertRatio(samples_per_insert=4, min_size=10, error_buffer=8)
    signature = Signature.from_dict(SCALAR_SIGNATURE)
    return Table("t", max_size=100, signature=signature, rate_limiter=limiter,
                 seed=0, **SAMPLERS[case], **kwargs)  # fmt: skip


@pytest.mark.parametrize("case", sorted(SAMPLERS))
def test_batches_drawn_together_are_admitted_and_counted_one_by_one(case):
    together, one_by_one = ratio_table(case), ratio_table(case)
    for table in (together, one_by_one):
        table.insert(scalar_batch(range(20)))  # 10 beyond min_size: 40 samples + 8 slack
    # One by one, the limiter admits a batch while at most 48 samples were drawn: 7 of 8.
    admitted = 0
    while one_by_one.try_sample(B) is not None:
        admitted += 1
    assert admitted == 7

    sampled = together.try_sample_batches(B, 10)
    assert sampled is not None
    batch, count = sampled
    assert count == admitted
    assert together.stats.samples == one_by_one.stats.samples == admitted * B
    assert together.try_sample_batches(B, 10) is None  # the limiter holds the 8th
    assert {len(column) for column in batch.values()} == {count * B}
    np.testing.assert_array_equal(batch["x"], batch["_key"].astype(np.int64))  # x = key

    together.insert(scalar_batch(range(20, 22)))  # 2 inserts: 8 more samples, one batch
    again = together.try_sample_batches(B, 10)
    assert again is not None and again[1] == 1


def test_a_fifo_table_gives_every_batch_of_a_response_the_oldest_items():
    table = ratio_table("fifo")
    table.insert(scalar_batch(range(20)))
    sampled = table.try_sample_batches(B, 3)
    assert sampled is not None
    batches = split_batch(sampled[0], sampled[1])
    assert [b["x"].tolist() for b in batches] == [list(range(B))] * 3


def test_prioritized_weights_are_normalised_within_each_batch():
    table = ratio_table("prioritized")
    table.insert(scalar_batch(range(20)))
    table.update_priorities(np.arange(20), np.arange(1, 21, dtype=np.float64))
    sampled = table.try_sample_batches(B, 4)
    assert sampled is not None
    for batch in split_batch(sampled[0], sampled[1]):
        assert batch["_weight"].max() == 1.0  # w_i / max_j w_j of its own batch


def test_every_batch_drawn_together_is_logged_on_its_own():
    table = ratio_table("uniform")
    logged: list[tuple[str, int]] = []
    table.log_samples(lambda name, items: logged.append((name, items)))
    table.insert(scalar_batch(range(20)))
    sampled = table.try_sample_batches(B, 10)
    assert sampled is not None
    assert logged == [("t", B)] * sampled[1]


def test_item_major_storage_returns_every_column_as_inserted():
    signature = Signature.from_dict(
        {
            "flag": {"dtype": "bool", "shape": []},
            "grid": {"dtype": "float16", "shape": [2, 3]},
            "count": {"dtype": "int64", "shape": []},
            "small": {"dtype": "uint8", "shape": [3]},
            "nothing": {"dtype": "float32", "shape": [0]},
        }
    )
    table = Table("t", max_size=50, signature=signature, sampler=make_sampler("fifo"))
    rng = np.random.default_rng(0)
    inserted = {
        "flag": rng.random(40) < 0.5,
        "grid": rng.random((40, 2, 3)).astype(np.float16),
        "count": rng.integers(-(2**40), 2**40, 40),
        "small": rng.integers(0, 255, (40, 3)).astype(np.uint8),
        "nothing": np.zeros((40, 0), np.float32),
    }
    table.insert(inserted)
    batch = table.sample(40)
    for name, column in inserted.items():
        assert batch[name].dtype == column.dtype
        np.testing.assert_array_equal(batch[name], column, err_msg=name)
        assert batch[name].flags.c_contiguous


def test_split_batch_refuses_columns_that_do_not_divide():
    batch = {"x": np.arange(10)}
    assert [b["x"].tolist() for b in split_batch(batch, 2)] == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]
    with pytest.raises(CodecError, match="multiple of 3"):
        split_batch(batch, 3)
    with pytest.raises(CodecError, match="all equal"):
        split_batch({"x": np.arange(4), "y": np.arange(6)}, 2)


# ----------------------------------------------------------- over a real server

TABLES = [
    {"name": "plain", "max_size": 1000, "signature": SCALAR_SIGNATURE},
    {
        "name": "ratio",
        "max_size": 1000,
        "signature": SCALAR_SIGNATURE,
        "rate_limiter": {
            "kind": "sample_to_insert_ratio",
            "samples_per_insert": 4,
            "min_size": 10,
            "error_buffer": 8,
        },
    },
]


@pytest.fixture(scope="module")
def client():
    with ReplayProcess(TABLES) as server:
        c = ReplayClient(server.address, max_retries=0)
        yield c
        c.close()


def _samples(client: ReplayClient, table: str) -> int:
    return next(t.samples for t in client.info() if t.name == table)


def _requests(*requests: replay_pb2.SampleRequest):
    yield from requests


@pytest.mark.service
def test_a_response_stacks_up_to_batches_per_message_within_the_credits(client):
    client.insert("plain", scalar_batch(range(100)))
    before = _samples(client, "plain")
    request = replay_pb2.SampleRequest(table="plain", batch_size=B, num_batches=10,
                                       batches_per_message=4)  # fmt: skip
    call = client.stub.Sample(_requests(request))
    responses = [next(call) for _ in range(3)]
    call.cancel()
    assert [r.num_batches for r in responses] == [4, 4, 2]  # 10 credits, 4 at most a message
    for r in responses:
        batch = decode_batch(r.batch)
        assert len(batch["x"]) == r.num_batches * B
        np.testing.assert_array_equal(batch["x"], batch["_key"].astype(np.int64))
    assert _samples(client, "plain") - before == 10 * B


@pytest.mark.service
def test_a_client_that_does_not_ask_gets_one_batch_per_response(client):
    client.insert("plain", scalar_batch(range(100, 110)))
    call = client.stub.Sample(_requests(replay_pb2.SampleRequest(table="plain", batch_size=B,
                                                                 num_batches=2)))  # fmt: skip
    responses = [next(call) for _ in range(2)]
    call.cancel()
    assert [r.num_batches for r in responses] == [1, 1]
    assert [len(decode_batch(r.batch)["x"]) for r in responses] == [B, B]


@pytest.mark.service
def test_a_response_carries_what_the_limiter_admits_now_and_the_rest_follows(client):
    client.insert("ratio", scalar_batch(range(20)))  # admits 7 batches of 8, as one by one
    request = replay_pb2.SampleRequest(table="ratio", batch_size=B, num_batches=10,
                                       batches_per_message=10, timeout_s=30)  # fmt: skip
    call = client.stub.Sample(_requests(request))
    first = next(call)
    assert first.num_batches == 7  # sent at once, not held back to fill the message
    assert _samples(client, "ratio") == 7 * B
    client.insert("ratio", scalar_batch(range(20, 24)))  # 16 more samples: 2 batches
    second = next(call)
    call.cancel()
    assert second.num_batches == 2
    assert _samples(client, "ratio") == 9 * B


@pytest.mark.service
def test_a_prefetching_stream_yields_single_batches_and_keeps_its_window(client):
    client.insert("plain", scalar_batch(range(110, 210)))  # x = key throughout
    before = _samples(client, "plain")
    stream = client.sample_stream("plain", B, prefetch=8, batches_per_message=4)
    batches = [next(stream) for _ in range(21)]
    stream.close()
    assert all(len(b["x"]) == B for b in batches)
    wrong = [(b["x"], b["_key"]) for b in batches if not np.array_equal(b["x"], b["_key"])]
    assert not wrong, (wrong[:3], client.info())  # which rows, and what the tables hold
    sampled = (_samples(client, "plain") - before) // B
    assert 21 <= sampled <= 21 + 8  # never more than the prefetch window ahead
