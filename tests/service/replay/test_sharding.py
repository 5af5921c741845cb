"""Two replay shards behind one client: writers routed by id, samples drawn across both."""

from __future__ import annotations

import pickle
import threading

import numpy as np
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay.errors import DeadlineExceeded
from service.replay.sharding import ShardedReplayClient
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch

pytestmark = pytest.mark.service  # real server processes, or Ray

TABLE = [
    {
        "name": "t",
        "max_size": 10_000,
        "sampler": {"kind": "prioritized", "priority_exponent": 1.0},
        "signature": SCALAR_SIGNATURE,
    }
]


def test_two_shards_route_writers_and_sample_across_both():
    with ReplayProcess(TABLE) as a, ReplayProcess(TABLE) as b:
        addresses = [a.address, b.address]
        writers = [ShardedReplayClient(addresses, writer_id=f"writer-{i}") for i in range(8)]
        homes = [w.home for w in writers]
        assert set(homes) == {0, 1}, homes  # these ids hash to both shards
        for i, w in enumerate(writers):
            w.insert("t", scalar_batch(np.arange(i * 100, i * 100 + 100)))
        sizes = [t[0].size for t in writers[0].info()]
        assert sizes == [100 * homes.count(0), 100 * homes.count(1)]

        learner = pickle.loads(pickle.dumps(ShardedReplayClient(addresses, seed=0)))
        stream = learner.sample_stream("t", 100, prefetch=2)
        drawn = np.concatenate([next(stream)["x"] for _ in range(200)])
        stream.close()
        writer_of = drawn // 100
        # Every writer's items are reachable, in proportion to the items stored (uniform).
        counts = np.bincount(writer_of, minlength=8)
        assert counts.min() > 0
        np.testing.assert_allclose(counts / counts.sum(), 1 / 8, atol=0.05)

        # Priority updates go back to the right shard through the key's shard byte.
        batch = learner.sample("t", 50)
        target = int(batch["_key"][0])
        assert learner.update_priorities("t", [target], [1e9]) == 1
        home = target >> 56
        hits = 0
        for _ in range(20):
            sample = learner.shards[home].sample("t", 100)
            hits += int((sample["x"] == batch["x"][0]).sum())
        assert hits > 1900


LIMITED = [
    {
        "name": "t",
        "max_size": 10_000,
        "signature": SCALAR_SIGNATURE,
        "rate_limiter": {
            "kind": "sample_to_insert_ratio", "samples_per_insert": 1.0, "min_size": 10,
            "error_buffer": 10.0,
        },
    }
]  # fmt: skip


def test_a_shard_whose_limiter_holds_samples_does_not_stall_the_stream():
    # Shard 0's writer stops after 10 items; shard 1's keeps inserting, paced by its
    # limiter. Each limiter admits about as many samples as its shard got items, so once
    # shard 0's are drawn the stream must go on with shard 1's instead of waiting on
    # shard 0 (whose actors might never come back).
    with ReplayProcess(LIMITED) as a, ReplayProcess(LIMITED) as b:
        addresses = [a.address, b.address]
        pinned = [ShardedReplayClient(addresses, home=k) for k in (0, 1)]
        assert [pickle.loads(pickle.dumps(w)).home for w in pinned] == [0, 1]
        pinned[0].insert("t", scalar_batch(np.arange(10)))
        stop = threading.Event()

        def keep_inserting() -> None:
            start = 1000
            while not stop.is_set():
                try:
                    pinned[1].insert("t", scalar_batch(np.arange(start, start + 5)), timeout=1)
                    start += 5
                except DeadlineExceeded:
                    pass  # held by the limiter: try again

        writer = threading.Thread(target=keep_inserting)
        writer.start()
        stream = ShardedReplayClient(addresses, seed=0).sample_stream("t", 5, prefetch=2)
        try:
            drawn = [stream.next_within(10.0) for _ in range(40)]
        finally:
            stream.close()
            stop.set()
            writer.join()
        shard_of = [int(batch["_key"][0]) >> 56 for batch in drawn]
        assert 2 <= shard_of.count(0) <= 3, shard_of  # all shard 0 admits (10 items)
        assert all(b["x"].max() < 10 if k == 0 else b["x"].min() >= 1000
                   for b, k in zip(drawn, shard_of, strict=True))  # fmt: skip
