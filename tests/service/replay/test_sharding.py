"""Two replay shards behind one client: writers routed by id, samples drawn across both."""

from __future__ import annotations

import pickle

import numpy as np

from service.replay.sharding import ShardedReplayClient
from service.run.replay_process import ReplayProcess
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch

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
