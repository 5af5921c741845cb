"""The replay server's worker pool: bounded, hottest thread first, jobs never lost."""

from __future__ import annotations

import threading

import pytest

from service.replay.server.thread_pool import HotThreadPool


def test_sequential_jobs_after_a_burst_stay_on_one_thread():
    pool = HotThreadPool(8)
    release = threading.Event()
    burst = [pool.submit(release.wait, 30) for _ in range(8)]  # eight threads busy at once
    release.set()
    assert all(f.result(30) for f in burst)
    names = {pool.submit(lambda: threading.current_thread().name).result(30) for _ in range(20)}
    assert len(names) == 1
    pool.shutdown()


def test_jobs_beyond_the_bound_wait_and_all_run():
    pool = HotThreadPool(2)
    release = threading.Event()
    blockers = [pool.submit(release.wait, 30) for _ in range(2)]
    queued = [pool.submit(lambda i=i: i * i) for i in range(10)]
    assert not any(f.done() for f in queued)
    release.set()
    assert [f.result(30) for f in queued] == [i * i for i in range(10)]
    assert all(f.result(30) for f in blockers)
    threads = {t.name for t in threading.enumerate() if t.name.startswith("pool_")}
    pool.shutdown()
    assert len(threads) <= 2


def test_errors_reach_the_caller_and_shutdown_refuses_new_jobs():
    pool = HotThreadPool(1)
    with pytest.raises(ZeroDivisionError):
        pool.submit(lambda: 1 / 0).result(30)
    assert pool.submit(lambda: "still working").result(30) == "still working"
    pool.shutdown()
    with pytest.raises(RuntimeError, match="after shutdown"):
        pool.submit(print)
