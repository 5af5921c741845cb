"""ReplayCore.commit in-process: a stream is stored whole or not at all, once."""

from __future__ import annotations

import threading

import pytest

from service.replay.codec import encode_batch
from service.replay.server import durability
from service.replay.server.durability import StorageError
from service.replay.server.store import CallEnded, ReplayCore, StagedInsert
from service.replay.server.table import LockBusy
from service.replay.server.table_config import make_table
from tests.service.replay.helpers import SCALAR_SIGNATURE, scalar_batch


def core(checkpoint_dir=None) -> ReplayCore:
    return ReplayCore(
        [make_table({"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE})],
        checkpoint_dir=checkpoint_dir,
    )


def staged(c: ReplayCore, values, *, writer: str = "w", sequence: int = 1) -> StagedInsert:
    batch = scalar_batch(values)
    return StagedInsert("t", c.table("t").prepare(batch), writer, sequence, encode_batch(batch))


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


class _DiskFillsUp:
    """A log file that takes `room` more bytes, then fails as a full disk does."""

    def __init__(self, file, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(28, "No space left on device")
        taken = self.file.write(data[: self.room])
        self.room -= taken
        return taken

    def __getattr__(self, name):
        return getattr(self.file, name)


def test_a_stream_whose_log_append_fails_is_neither_stored_nor_logged(tmp_path):
    c = core(tmp_path)
    assert c.commit([staged(c, [1], sequence=1)]) == (1, 0)
    wal = c._wal
    assert wal is not None
    logged = durability.segment_path(tmp_path, wal.segment).stat().st_size
    real = wal._file
    wal._file = _DiskFillsUp(real, room=logged)  # room for about one of the two records
    stream = [staged(c, [2], sequence=2), staged(c, [3], sequence=3)]
    with pytest.raises(StorageError):
        c.commit(stream)
    assert (c.table("t").size, c.writers.acked("w")) == (1, 1)
    assert c.durability.log_append_failures == 1
    assert durability.segment_path(tmp_path, wal.segment).stat().st_size == logged
    wal._file = real  # space again: the client's resend is stored, once
    assert c.commit(stream) == (2, 0)
    c.close()
    again = core(tmp_path)
    assert (again.table("t").size, again.writers.acked("w")) == (3, 3)
    again.close()


def test_a_sample_whose_log_record_fails_is_served_and_counted_in_memory_only(tmp_path):
    c = core(tmp_path)
    assert c.commit([staged(c, [1, 2, 3], sequence=1)]) == (3, 0)
    c.table("t").sample(2)  # logged
    wal = c._wal
    assert wal is not None
    real = wal._file
    wal._file = _DiskFillsUp(real, room=0)
    assert len(c.table("t").sample(2)["x"]) == 2  # served although its record failed
    assert (c.table("t").stats.samples, c.durability.unlogged_samples) == (4, 2)
    assert c.durability.log_append_failures == 0  # no insert was refused
    wal._file = real
    c.table("t").sample(2)  # logged again
    c.close()
    again = core(tmp_path)
    assert again.table("t").stats.samples == 4  # the two logged batches, not the unlogged one
    again.close()
