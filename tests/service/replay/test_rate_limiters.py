"""Rate limiters admit calls by the ratio they hold, refuse settings that cannot work,
and a table blocked by one times out cleanly."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from service.replay.server.rate_limiters import MinSize, SampleToInsertRatio
from service.replay.server.signature import Signature
from service.replay.server.table import RateLimitTimeout, Table

SIGNATURE = Signature.from_dict({"x": {"dtype": "float32", "shape": []}})


def batch(n: int) -> dict[str, np.ndarray]:
    return {"x": np.zeros(n, np.float32)}


def test_min_size_blocks_samples_until_enough_items():
    limiter = MinSize(10)
    assert not limiter.sample_allowed(size=9, inserts=9, samples=0)
    assert limiter.sample_allowed(size=10, inserts=10, samples=0)
    assert limiter.insert_allowed(inserts=10**9, samples=0)


@pytest.mark.parametrize(
    ("inserts", "samples", "insert_ok", "sample_ok"),
    [
        (5, 0, True, False),  # below min_size: insert freely, never sample
        (10, 0, True, True),  # at min_size: balanced
        (13, 0, False, True),  # 3 inserts × 4 = 12 samples ahead > buffer 8: inserts wait
        (12, 8, True, True),
        (10, 9, True, False),  # learner 9 samples ahead > buffer 8: samples wait
    ],
)
def test_sample_to_insert_ratio_admission(inserts, samples, insert_ok, sample_ok):
    limiter = SampleToInsertRatio(samples_per_insert=4, min_size=10, error_buffer=8)
    assert limiter.insert_allowed(inserts=inserts, samples=samples) is insert_ok
    assert limiter.sample_allowed(size=inserts, inserts=inserts, samples=samples) is sample_ok


def test_sample_credit_is_a_burn_in_at_min_size_that_holds_inserts_until_spent():
    limiter = SampleToInsertRatio(
        samples_per_insert=4, min_size=10, error_buffer=8, sample_credit=40
    )
    # At min_size the learner may draw 40 + 8 samples before it waits, not 8.
    assert limiter.sample_allowed(size=10, inserts=10, samples=48)
    assert not limiter.sample_allowed(size=10, inserts=10, samples=49)
    # Inserts wait while more than the buffer of credit is unspent: 40 - 31 = 9 > 8.
    assert not limiter.insert_allowed(inserts=10, samples=31)
    assert limiter.insert_allowed(inserts=10, samples=32)  # 40 - 32 = 8: back in balance
    with pytest.raises(ValueError, match="sample_credit"):
        SampleToInsertRatio(samples_per_insert=4, min_size=10, error_buffer=8, sample_credit=-1)


def test_error_buffer_smaller_than_ratio_is_refused_with_reason():
    with pytest.raises(ValueError, match="lock-step"):
        SampleToInsertRatio(samples_per_insert=16, min_size=1, error_buffer=4)


def test_min_size_above_max_size_is_refused():
    with pytest.raises(ValueError, match="sampling could never start"):
        Table("t", max_size=5, signature=SIGNATURE, rate_limiter=MinSize(6))


def test_blocked_sample_times_out_and_table_still_works():
    table = Table("t", max_size=100, signature=SIGNATURE, rate_limiter=MinSize(10))
    table.insert(batch(5))
    start = time.monotonic()
    with pytest.raises(RateLimitTimeout, match="sample not admitted"):
        table.sample(4, timeout=0.2)
    assert 0.15 < time.monotonic() - start < 5
    table.insert(batch(5))
    assert table.sample(4, timeout=1)["x"].shape == (4,)


def test_ratio_holds_under_concurrent_writers_and_sampler():
    limiter = SampleToInsertRatio(samples_per_insert=2, min_size=20, error_buffer=40)
    table = Table("t", max_size=10_000, signature=SIGNATURE, rate_limiter=limiter)
    worst, errors = [0.0], []

    def write():
        try:
            for _ in range(50):
                table.insert(batch(10), timeout=10)
        except Exception as error:
            errors.append(error)

    def read():
        try:
            # (2,000 inserts − min_size 20) × 2 = 3,960 samples, + the 40 buffer = 200 batches.
            for _ in range(200):
                table.sample(20, timeout=10)
                s = table.stats
                worst[0] = max(worst[0], abs(s.inserts * 2 - s.samples - 40))
        except Exception as error:
            errors.append(error)

    threads = [threading.Thread(target=write) for _ in range(4)] + [threading.Thread(target=read)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not any(t.is_alive() for t in threads)
    assert errors == []
    assert (table.stats.inserts, table.stats.samples) == (2000, 4000)
    # Within the buffer plus one batch of overshoot on either side.
    assert worst[0] <= 40 + max(10 * 2, 20)


@pytest.mark.service
def test_ratio_holds_over_grpc_with_concurrent_clients():
    """A real server process: 4 writer clients and a sampling client, ratio 2 ± 40."""
    from graft.replay_host.process import ReplayProcess
    from service.replay.client import ReplayClient
    from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch

    limiter = {"kind": "sample_to_insert_ratio", "samples_per_insert": 2, "min_size": 20,
               "error_buffer": 40}  # fmt: skip
    table = [{"name": "t", "max_size": 10_000, "rate_limiter": limiter,
              "signature": SCALAR_SIGNATURE}]  # fmt: skip
    with ReplayProcess(table) as server:
        errors, worst = [], [0]
        done = threading.Event()

        def write():
            client = ReplayClient(server.address)
            try:
                for _ in range(50):
                    client.insert("t", scalar_batch(range(10)), timeout=20)
            except Exception as error:
                errors.append(error)

        def read():
            client = ReplayClient(server.address)
            try:
                for _ in range(200):
                    client.sample("t", 20, timeout=20)
            except Exception as error:
                errors.append(error)

        def watch():
            client = ReplayClient(server.address)
            while not done.is_set():
                t = client.info()[0]
                worst[0] = max(worst[0], abs(t.inserts * 2 - t.samples - 40))
                time.sleep(0.01)

        threads = [threading.Thread(target=f) for f in [write] * 4 + [read]]
        watcher = threading.Thread(target=watch)
        watcher.start()
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        done.set()
        watcher.join()
        assert errors == []
        t = ReplayClient(server.address).info()[0]
        assert (t.inserts, t.samples) == (2000, 4000)
        assert worst[0] <= 40 + 4 * 10 * 2  # buffer, plus one batch per concurrent writer
        assert t.rate_limiter_blocked_s > 0  # someone actually had to wait
