"""ReplayCore.commit in-process: a stream is stored whole or not at all, once."""

from __future__ import annotations

import threading

import pytest

from service.replay.server.store import CallEnded, ReplayCore, StagedInsert
from service.replay.server.table import LockBusy
from service.replay.server.table_config import make_table
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch


def core() -> ReplayCore:
    return ReplayCore([make_table({"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE})])


def staged(c: ReplayCore, values, *, writer: str = "w", sequence: int = 1) -> StagedInsert:
    prepared = c.table("t").prepare(scalar_batch(values))
    return StagedInsert("t", prepared, writer, sequence)


def test_a_commit_that_meets_a_held_lock_stores_nothing_unless_it_may_block():
    c = core()
    held, release = threading.Event(), threading.Event()

    def hold() -> None:  # another thread, e.g. a checkpoint taking its snapshot
        with c.table("t").lock:
            held.set()
            release.wait(30)

    holder = threading.Thread(target=hold)
    holder.start()
    held.wait(30)
    with pytest.raises(LockBusy):
        c.commit([staged(c, [1, 2])], blocking=False)
    with pytest.raises(LockBusy):
        c.table("t").try_sample(1, blocking=False)
    release.set()
    holder.join()
    assert (c.table("t").size, c.writers.acked("w")) == (0, 0)
    assert c.commit([staged(c, [1, 2])], blocking=False) == (2, 0)


def test_a_commit_for_a_call_that_ended_stores_nothing():
    c = core()
    with pytest.raises(CallEnded):
        c.commit([staged(c, [1, 2])], alive=lambda: False)
    assert (c.table("t").size, c.writers.acked("w")) == (0, 0)


def test_resends_in_and_across_streams_are_dropped():
    c = core()
    assert c.commit([staged(c, [1], sequence=1), staged(c, [2], sequence=2)]) == (2, 0)
    again = [staged(c, [2], sequence=2), staged(c, [3], sequence=3), staged(c, [3], sequence=3)]
    assert c.commit(again) == (1, 2)
    assert (c.table("t").size, c.writers.acked("w")) == (3, 3)
