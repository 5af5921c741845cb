"""Tables on a real server process: samplers, windows, priorities, statuses."""

from __future__ import annotations

import grpc
import numpy as np
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch
from service.replay.errors import DeadlineExceeded, InvalidArgument, TableNotFound
from service.replay.server.table_config import make_table
from tests.service.replay.helpers import SCALAR_SIGNATURE, read_all, scalar_batch

pytestmark = pytest.mark.service  # a real server process per module

# Chi-square critical value for 99 degrees of freedom at p = 0.001.
CHI2_99_P001 = 148.2

TABLES = [
    {"name": "uniform", "max_size": 100, "signature": SCALAR_SIGNATURE},
    {"name": "fifo", "max_size": 100, "sampler": "fifo", "signature": SCALAR_SIGNATURE},
    {"name": "lifo", "max_size": 100, "sampler": "lifo", "signature": SCALAR_SIGNATURE},
    {
        "name": "prioritized",
        "max_size": 100,
        "sampler": {"kind": "prioritized", "priority_exponent": 1.0, "importance_exponent": 1.0},
        "signature": SCALAR_SIGNATURE,
    },
    {
        "name": "windows",
        "max_size": 1000,
        "max_sequence_length": 4,
        "signature": {**SCALAR_SIGNATURE, "episode": {"dtype": "int64", "shape": []}},
    },
    {
        "name": "open_windows",
        "max_size": 100,
        "max_sequence_length": 3,
        "signature": SCALAR_SIGNATURE,
    },
    {
        "name": "queue",
        "max_size": 10,
        "sampler": "fifo",
        "max_times_sampled": 1,
        "signature": SCALAR_SIGNATURE,
    },
    {
        "name": "lifo_remover",
        "max_size": 5,
        "sampler": "fifo",
        "remover": "lifo",
        "signature": SCALAR_SIGNATURE,
    },
    {
        "name": "warmup",
        "max_size": 100,
        "rate_limiter": {"kind": "min_size", "min_size": 50},
        "signature": SCALAR_SIGNATURE,
    },
    *(
        {"name": name, "max_size": 100, "seed": seed, "signature": SCALAR_SIGNATURE}
        for name, seed in (("seeded", 7), ("seeded_again", 7), ("seeded_other", 8))
    ),
]


@pytest.fixture(scope="module")
def client():
    with ReplayProcess(TABLES, extra_args=["--max-message-mb", "1"]) as server:
        c = ReplayClient(server.address, max_retries=0)
        yield c
        c.close()


def chi_square(counts: np.ndarray, expected: np.ndarray) -> float:
    return float(((counts - expected) ** 2 / expected).sum())


def test_uniform_sampler_is_uniform(client):
    client.insert("uniform", scalar_batch(range(100)))
    draws = np.concatenate([client.sample("uniform", 1000)["x"] for _ in range(20)])
    counts = np.bincount(draws, minlength=100)
    assert chi_square(counts, np.full(100, 200.0)) < CHI2_99_P001
    batch = client.sample("uniform", 10)
    np.testing.assert_allclose(batch["_probability"], 0.01)
    np.testing.assert_array_equal(batch["_weight"], 1.0)


def test_prioritized_sampler_follows_priorities_and_updates(client):
    batch = scalar_batch(range(100))
    batch["_priority"] = np.arange(1, 101, dtype=np.float64)  # p_i = i + 1
    client.insert("prioritized", batch)
    draws = np.concatenate([client.sample("prioritized", 1000)["x"] for _ in range(20)])
    expected = 20_000 * np.arange(1, 101) / np.arange(1, 101).sum()
    assert chi_square(np.bincount(draws, minlength=100), expected) < CHI2_99_P001
    sample = client.sample("prioritized", 64)
    p = (sample["x"] + 1) / np.arange(1, 101).sum()
    np.testing.assert_allclose(sample["_probability"], p)
    w = (100 * p) ** -1.0
    np.testing.assert_allclose(sample["_weight"], w / w.max(), rtol=1e-6)
    # Raising one item's priority far above the rest makes it dominate the samples.
    key_of_zero = int(sample["_key"][0] - sample["x"][0])  # keys follow insertion order
    assert client.update_priorities("prioritized", [key_of_zero], [1e6]) == 1
    draws = client.sample("prioritized", 1000)["x"]
    assert (draws == 0).mean() > 0.95


def test_fifo_and_lifo_samplers_give_oldest_and_newest(client):
    client.insert("fifo", scalar_batch(range(10)))
    client.insert("lifo", scalar_batch(range(10)))
    np.testing.assert_array_equal(client.sample("fifo", 3)["x"], [0, 1, 2])
    np.testing.assert_array_equal(client.sample("lifo", 3)["x"], [9, 8, 7])


def test_max_times_sampled_turns_a_table_into_a_queue(client):
    client.insert("queue", scalar_batch(range(6)))
    np.testing.assert_array_equal(client.sample("queue", 4)["x"], [0, 1, 2, 3])
    np.testing.assert_array_equal(client.sample("queue", 2)["x"], [4, 5])
    assert next(t.size for t in client.info() if t.name == "queue") == 0


def test_lifo_remover_evicts_the_newest(client):
    client.insert("lifo_remover", scalar_batch(range(5)))
    client.insert("lifo_remover", scalar_batch([100]))
    np.testing.assert_array_equal(read_all(client, "lifo_remover"), [0, 1, 2, 3, 100])


def test_windows_follow_one_episode_and_repeat_its_last_step_after_its_end(client):
    # Two interleaved streams (as one actor's two environments), episodes of varied length.
    rng = np.random.default_rng(0)
    per_stream: list[list[tuple[int, int, int, bool]]] = [[], []]
    for stream in (0, 1):
        step = 0
        for episode in range(12):
            length = int(rng.integers(1, 9))
            for t in range(length):
                per_stream[stream].append((stream, 1000 * stream + episode, step, t == length - 1))
                step += 1
    rows = []  # interleave the streams at random, keeping each stream's own order
    while per_stream[0] or per_stream[1]:
        pick = int(rng.integers(2)) if per_stream[0] and per_stream[1] else int(not per_stream[0])
        rows.append(per_stream[pick].pop(0))
    stream, episode, step, end = (np.array(c) for c in zip(*rows, strict=True))
    batch = scalar_batch(step, ends=end)
    batch["episode"] = episode
    batch["_stream"] = stream
    for half in (slice(0, len(step) // 2), slice(len(step) // 2, None)):  # links span inserts
        client.insert("windows", {k: v[half] for k, v in batch.items()})
    sample = client.sample("windows", 2000, sequence_length=4)
    valid = sample["_valid"]
    assert sample["x"].shape == valid.shape == (2000, 4)
    assert (sample["episode"] == sample["episode"][:, :1]).all()  # one episode per window
    moves = np.diff(sample["x"], axis=1)
    np.testing.assert_array_equal(moves[valid[:, 1:]], 1)  # the episode's steps, in order
    np.testing.assert_array_equal(moves[~valid[:, 1:]], 0)  # then its last step, repeated
    assert valid[:, 0].all() and (valid[:, :-1] >= valid[:, 1:]).all()  # a prefix
    last = valid.sum(axis=1) - 1
    ends = sample["terminated"][np.arange(len(last)), last]
    assert ends[~valid[:, -1]].all()  # padding only after an episode's end
    assert not (sample["terminated"][:, :-1] & valid[:, 1:]).any()  # no end inside a window
    # Every step starts windows: the last 3 of each episode, and episodes of 1-3 steps, too.
    assert {(s, x) for s, x in zip(stream, step, strict=True)} == {
        (e // 1000, x) for e, x in zip(sample["episode"][:, 0], sample["x"][:, 0], strict=True)
    }
    with pytest.raises(InvalidArgument, match="outside \\[1, 4\\]"):
        client.sample("windows", 1, sequence_length=5)


def test_a_window_waits_for_the_next_step_of_an_episode_that_goes_on(client):
    client.insert("open_windows", scalar_batch([0, 1]))  # an episode two steps in
    with pytest.raises(DeadlineExceeded):
        client.sample("open_windows", 1, sequence_length=3, timeout=0.3)
    client.insert("open_windows", scalar_batch([2], ends=[True]))  # its third step ends it
    sample = client.sample("open_windows", 300, sequence_length=3, timeout=5)
    windows = zip(sample["x"], sample["_valid"], strict=True)
    by_start = {int(w[0]): (w.tolist(), v.tolist()) for w, v in windows}
    assert by_start == {
        0: ([0, 1, 2], [True, True, True]),
        1: ([1, 2, 2], [True, True, False]),
        2: ([2, 2, 2], [True, False, False]),
    }


def test_sample_below_min_size_times_out_with_deadline_exceeded(client):
    client.insert("warmup", scalar_batch(range(10)))
    with pytest.raises(DeadlineExceeded, match="not admitted"):
        client.sample("warmup", 4, timeout=0.3)
    client.insert("warmup", scalar_batch(range(40)))
    assert client.sample("warmup", 4, timeout=5)["x"].shape == (4,)


def test_unknown_table_is_not_found(client):
    with pytest.raises(TableNotFound, match="tables are"):
        client.sample("nope", 1)
    with pytest.raises(TableNotFound):
        client.insert("nope", scalar_batch([1]))


def test_oversize_message_is_resource_exhausted_and_changes_nothing(client):
    client.insert("uniform", scalar_batch(range(100)))
    before = next(t for t in client.info() if t.name == "uniform")
    huge = scalar_batch(np.arange(200_000))  # ~2 MiB > the server's 1 MiB limit
    request = replay_pb2.InsertRequest(table="uniform", batch=encode_batch(huge))
    with pytest.raises(grpc.RpcError) as caught:
        client.stub.Insert(iter([request]))
    assert caught.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    after = next(t for t in client.info() if t.name == "uniform")
    assert (after.size, after.inserts) == (before.size, before.inserts)


def test_priorities_on_a_uniform_table_are_refused(client):
    with pytest.raises(InvalidArgument, match="not by priority"):
        client.update_priorities("uniform", [0], [1.0])
    bad = scalar_batch([1])
    bad["_priority"] = np.array([1.0])
    with pytest.raises(InvalidArgument, match="does not sample by priority"):
        client.insert("uniform", bad)


def test_negative_priority_is_refused(client):
    with pytest.raises(InvalidArgument, match="finite and >= 0"):
        client.update_priorities("prioritized", [0], [-1.0])


def test_a_seeded_sampler_draws_the_same_items_from_the_same_inserts(client):
    drawn = {}
    for table in ("seeded", "seeded_again", "seeded_other"):
        client.insert(table, scalar_batch(range(100)))
        stream = client.sample_stream(table, 16, prefetch=0)  # each batch drawn when asked
        drawn[table] = [stream.next_within(5)["x"] for _ in range(3)]
        assert stream.table_inserts == 100
    assert np.array_equal(drawn["seeded"], drawn["seeded_again"])
    assert not np.array_equal(drawn["seeded"], drawn["seeded_other"])


def test_a_table_seed_must_be_a_non_negative_integer():
    spec = {"name": "t", "max_size": 10, "signature": SCALAR_SIGNATURE, "seed": -1}
    with pytest.raises(ValueError, match="seed=-1 must be an integer >= 0"):
        make_table(spec)
