"""The background writer against a real replay server: inserts arrive, a rate limiter
that holds inserts still holds the actor back (back-pressure, never loss), and a failed
background insert is raised on the acting thread."""

from __future__ import annotations

import threading
import time

import pytest

from actors.writer import BackgroundWriter
from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient
from service.replay.errors import TableNotFound
from tests.conftest import PENDULUM_SIGNATURE, pendulum_batch


def test_inserts_arrive_and_flush_waits_for_them(replay_client: ReplayClient) -> None:
    writer = BackgroundWriter(replay_client)
    for i in range(5):
        writer.insert("transitions", pendulum_batch(8, start=8 * i), max_pending=8)
    writer.flush(timeout_s=30)
    assert writer.pending() == 0 and writer.inserted == 40
    (status,) = replay_client.info()
    assert status.size == 40
    writer.close()


def test_max_pending_zero_returns_once_stored(replay_client: ReplayClient) -> None:
    writer = BackgroundWriter(replay_client)
    for i in range(3):
        writer.insert("transitions", pendulum_batch(4, start=4 * i), max_pending=0)
        (status,) = replay_client.info()
        assert status.size == 4 * (i + 1)  # stored before insert returned
    writer.close()


@pytest.mark.service
def test_a_rate_limiter_holding_inserts_holds_the_actor_back() -> None:
    # One sample per inserted item, 4 items before sampling, slack 1: two batches of 4 go
    # in, the third waits until the learner has sampled 3 more items.
    table = {
        "name": "held", "max_size": 100, "signature": PENDULUM_SIGNATURE,
        "rate_limiter": {
            "kind": "sample_to_insert_ratio", "samples_per_insert": 1.0, "min_size": 4,
            "error_buffer": 1.0,
        },
    }  # fmt: skip
    with ReplayProcess([table]) as server:
        actor_side, learner_side = ReplayClient(server.address), ReplayClient(server.address)
        writer = BackgroundWriter(actor_side)
        writer.insert("held", pendulum_batch(4, 0), max_pending=1)
        writer.insert("held", pendulum_batch(4, 4), max_pending=1)
        writer.flush(timeout_s=30)
        writer.insert("held", pendulum_batch(4, 8), max_pending=1)  # held; one may wait
        returned = threading.Event()

        def act_on() -> None:
            writer.insert("held", pendulum_batch(4, 12), max_pending=1)
            returned.set()

        thread = threading.Thread(target=act_on)
        thread.start()
        deadline = time.monotonic() + 30
        # Both batches given and the third one's call under way (on a loaded machine the
        # sender may not have taken it from the queue yet when both are pending).
        while (
            writer.pending() < 2 or writer.insert_call_s() == writer.insert_s
        ) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert writer.pending() == 2
        held_from = writer.insert_call_s()
        time.sleep(0.3)
        assert not returned.is_set()  # acting waits: nothing is dropped to let it go on
        # The held call counts while it is held, not only once it returns.
        assert writer.insert_call_s() - held_from >= 0.3
        learner_side.sample("held", 4)  # the limiter admits the third batch ...
        assert returned.wait(30)  # ... so one batch waits again and acting goes on
        learner_side.sample("held", 4)  # ... and the fourth
        writer.flush(timeout_s=30)
        thread.join()
        (status,) = learner_side.info()
        assert status.size == 16 and writer.inserted == 16
        writer.close()
        actor_side.close()
        learner_side.close()


def test_a_failed_background_insert_is_raised_on_the_acting_thread(
    replay_client: ReplayClient,
) -> None:
    writer = BackgroundWriter(replay_client)
    writer.insert("no_such_table", pendulum_batch(4), max_pending=4)  # queued: returns
    with pytest.raises(TableNotFound):
        writer.flush(timeout_s=30)
    with pytest.raises(TableNotFound):  # and every later call, until the actor stops
        writer.insert("transitions", pendulum_batch(4), max_pending=4)
    assert writer.inserted == 0
    with pytest.raises(ValueError, match="max_pending"):
        BackgroundWriter(replay_client).insert("transitions", pendulum_batch(1), max_pending=-1)
