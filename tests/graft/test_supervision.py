"""Supervision: a killed replay server comes back on its port with its data, a dead actor's
share is taken over by a new actor, and every restart is counted."""

from __future__ import annotations

import os
import signal

import pytest
import ray

from actors.env_actor import Segment
from graft.orchestration.supervision import ActorFleet, remaining_segments
from graft.replay_host.supervised import SupervisedReplay, TooManyRestarts
from service.replay.client import ReplayClient
from tests.conftest import PENDULUM_SIGNATURE, pendulum_batch

DEMOS, ONLINE = Segment("demos", 100, 100, 8), Segment("transitions", 500, 50)


@pytest.mark.parametrize(
    "done, left",
    [
        (0, [DEMOS, ONLINE]),
        (60, [Segment("demos", 40, 40, 8), ONLINE]),
        (100, [ONLINE]),
        (130, [Segment("transitions", 470, 20)]),
        (200, [Segment("transitions", 400, 0)]),
        (600, []),
    ],
)
def test_remaining_segments(done, left) -> None:
    assert remaining_segments([DEMOS, ONLINE], done) == left


@pytest.mark.service
@pytest.mark.serial  # a port reused across a restart, or pacing
def test_a_killed_replay_server_restarts_on_its_port_with_its_data(tmp_path) -> None:
    tables = [{"name": "transitions", "max_size": 1000, "signature": PENDULUM_SIGNATURE}]
    replay = SupervisedReplay(
        tables, host="127.0.0.1", port=0, token=None, checkpoint_dir=tmp_path / "replay",
        checkpoint_every_s=60.0, log_path=tmp_path / "replay.log", max_restarts=1,
    )  # fmt: skip
    client = ReplayClient(replay.address, max_retries=40)
    try:
        assert replay.check() is None
        assert client.insert("transitions", pendulum_batch(30)) == 30
        os.kill(replay.process.process.pid, signal.SIGKILL)
        replay.process.process.wait()
        line = replay.check()
        assert line == (
            f"replay server died (exit code -9); restarted from its checkpoint folder on port "
            f"{replay.port} (restart 1)"
        )
        assert replay.process.address == replay.address  # clients keep their address
        # The acknowledged batch is back (from the log); the next one is stored once.
        assert client.insert("transitions", pendulum_batch(20, start=30)) == 20
        assert client.info()[0].size == 50
        os.kill(replay.process.process.pid, signal.SIGKILL)
        replay.process.process.wait()
        with pytest.raises(TooManyRestarts, match="replay.max_restarts=1"):
            replay.check()
    finally:
        client.close()
        replay.stop()


@ray.remote(num_cpus=0, max_concurrency=2)  # as env actors: `report` answers during `run`
class ShareRecorder:
    """Stands in for an env actor: `run` records its share and holds until released, or
    returns at once when it is the replacement; `report` says what it stored."""

    def __init__(self, index: int, incarnation: int) -> None:
        self.incarnation = incarnation

    def run(self, segments: list[Segment]) -> dict:
        steps = sum(s.steps for s in segments)
        if self.incarnation == 0:
            import time

            time.sleep(600)  # killed before it ends
        return {"env_steps": steps, "versions_seen": [], "segments": segments}

    def report(self) -> dict:
        return {"replay/inserted": 30 if self.incarnation == 0 else 0}


def test_a_dead_actor_is_replaced_with_the_rest_of_its_share(ray_local) -> None:
    fleet = ActorFleet(
        lambda i, k: ShareRecorder.remote(i, k), [Segment("transitions", 100, 10)], 1,
        max_restarts=1,
    )  # fmt: skip
    slot = fleet.slots[0]
    assert ray.get(slot.actor.report.remote())["replay/inserted"] == 30
    fleet.check()  # learns what the actor stored
    ray.wait([slot.report], timeout=30)
    assert fleet.check() == []
    assert slot.stored == 30
    ray.kill(slot.actor, no_restart=True)
    ray.wait([slot.run], timeout=30)
    (line,) = fleet.check()
    assert "env actor 0 died" in line and "70 env steps of its share left" in line
    assert fleet.restarts == 1
    reports, stopped = fleet.reports(timeout_s=30)
    assert stopped == []
    # The replacement was given the rest (warm-up already done) and the total adds up.
    assert reports[0]["segments"] == [Segment("transitions", 70, 0)]
    assert reports[0]["env_steps"] == 100
