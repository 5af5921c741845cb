"""The shared step budget: actors claim each phase's steps in insert-batch chunks, so a
fast actor does most of the work and every actor acts until the phase is spent; a dead
actor's unfinished claims are acted by the others and its replacement; totals are exact.
Against a real local Ray, real env actors and a real replay server."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import ray
import torch

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import EnvActor, Segment
from actors.task import EnvSpec
from actors.transitions import replay_signature
from graft.orchestration.budget import Budget, BudgetClaims, StepBudget
from graft.orchestration.supervision import ActorFleet
from graft.replay_host.process import ReplayProcess
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from learner.td3.networks import acting_copy
from service.replay.client import ReplayClient
from service.weights import WeightBroadcaster, WeightSubscriber

ENV_ID = "usertask.envs:Reach1D-v0"
STEPS_PER_INSERT = 4
"""One claimed chunk: 4 vector steps of one environment."""


def test_claims_hand_out_each_step_once_and_a_release_gives_back_the_unstored() -> None:
    budget = Budget({"demos": 10, "online": 9, "pretrain": 0})
    assert budget.claim("a.0", "demos", 4, stored=0) == (0, 4)
    assert budget.claim("b.0", "demos", 4, stored=0) == (4, 4)
    assert budget.claim("a.0", "demos", 4, stored=4) == (8, 2)  # the last, shorter chunk
    assert budget.claim("b.0", "demos", 4, stored=4) == (0, 0)  # demos spent
    assert budget.claim("a.0", "pretrain", 4, stored=6) == (0, 0)  # no env steps
    assert budget.claim("a.0", "online", 4, stored=6) == (0, 4)
    # a.0 dies having stored demos [0, 4) and [8, 10) and the online chunk's first item
    # (seen by the supervisor, newer than its last claim): the other 3 come back.
    assert budget.release("a.0", stored=7) == 7
    assert budget.left() == {"demos": 0, "online": 8}
    # The returned steps are merged with the rest and claimed first.
    assert budget.claim("a.1", "online", 4, stored=0) == (1, 4)
    assert budget.claim("a.1", "online", 4, stored=4) == (5, 4)
    assert budget.claim("b.0", "online", 4, stored=4) == (0, 0)
    # A release that knows less than the claims did keeps what the claims said.
    assert budget.release("b.0", stored=0) == 4
    assert budget.left() == {"demos": 0, "online": 0}
    assert budget.release("a.1", stored=5) == 5  # a.1 dies with 3 steps of [5, 9) unstored
    assert budget.left() == {"demos": 0, "online": 3}
    with pytest.raises(ValueError, match="want=0"):
        budget.claim("c.0", "online", 0, stored=0)
    # A claim a dead actor sent (its next chunk, asked for ahead) that arrives after its
    # release grants nothing: those steps would never be acted.
    assert budget.claim("a.1", "online", 4, stored=5) == (0, 0)
    assert budget.left() == {"demos": 0, "online": 3}


def test_an_actors_claims_ask_for_the_next_chunk_while_it_acts(ray_local) -> None:
    budget = StepBudget.remote({"reach": 10})
    claims = BudgetClaims(budget, "a.0")
    assert claims.claim("reach", 4, stored=0) == (0, 4)
    assert ray.get(budget.left.remote()) == {"reach": 2}  # [4, 8) is on its way
    assert claims.claim("reach", 4, stored=4) == (4, 4)
    assert claims.claim("reach", 4, stored=8) == (8, 2)
    assert claims.claim("reach", 4, stored=10) == (0, 0)
    # The last request went out with stored=8 (when [8, 10) was handed over): dying now
    # gives back [8, 10), the chunk in flight, unless the supervisor saw it stored.
    assert ray.get(budget.release.remote("a.0", 0)) == 8
    assert ray.get(budget.left.remote()) == {"reach": 2}
    ray.kill(budget)


class CountingBehaviour(GaussianBehaviour):
    """Gaussian exploration that reports a behaviour scalar with every insert (as ε-greedy
    and options do), so the rows' run positions can be checked."""

    def stats(self) -> dict[str, float]:
        return {"inserts": 1.0}


ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the actors unpickle it


def behaviour() -> GaussianBehaviour:
    torch.manual_seed(0)
    network = make_actor_network(
        2, 1, np.array([-1.0]), np.array([1.0]), TD3Config(hidden_sizes=(8,))
    )
    return CountingBehaviour(
        acting_copy(network), std=0.1, low=np.array([-1.0]), high=np.array([1.0])
    )


@pytest.fixture
def replay() -> Iterator[ReplayClient]:
    env = EnvSpec(ENV_ID).make()
    signature = replay_signature(env.observation_space, behaviour().columns())
    with ReplayProcess([{"name": "reach", "max_size": 10_000, "signature": signature}]) as server:
        client = ReplayClient(server.address)
        yield client
        client.close()


def fleet(replay: ReplayClient, steps: int, step_s: list[float]) -> tuple[ActorFleet, Any]:
    """Env actors (actor i's env steps take `step_s[i]`) drawing one all-warm-up phase of
    `steps` from a shared budget; no weights are published (warm-up needs none)."""
    broadcaster = WeightBroadcaster.remote()

    def make(i: int, incarnation: int) -> Any:
        return EnvActor.options(max_concurrency=2).remote(
            env=EnvSpec(ENV_ID, {"step_s": step_s[i]}), num_envs=1, seed=10 * i + incarnation,
            replay=replay, weights=WeightSubscriber(broadcaster), behaviour=behaviour(),
            steps_per_insert=STEPS_PER_INSERT,
        )  # fmt: skip

    phase = Segment("reach", steps, steps, pending_inserts=0)
    budget = StepBudget.remote({"reach": steps})
    return ActorFleet(make, [phase], len(step_s), max_restarts=2, budget=budget), broadcaster


def finish_times(runs: list[Any], timeout_s: float) -> list[float]:
    """When each run call returned (monotonic), polled every 20 ms."""
    done: dict[int, float] = {}
    deadline = time.monotonic() + timeout_s
    while len(done) < len(runs) and time.monotonic() < deadline:
        for i, run in enumerate(runs):
            if i not in done and ray.wait([run], timeout=0)[0]:
                done[i] = time.monotonic()
        time.sleep(0.02)
    assert len(done) == len(runs), "the actors did not finish"
    return [done[i] for i in range(len(runs))]


@pytest.mark.serial  # a port reused across a restart, or pacing
def test_a_fast_actor_does_most_steps_and_both_act_until_the_end(ray_local, replay) -> None:
    # Steps of 5 ms and 40 ms: a slow chunk of 4 takes 0.16 s. With fixed shares (400
    # each) the fast actor would be done some 13 s before the slow one.
    actors, broadcaster = fleet(replay, 800, [0.005, 0.04])
    try:
        end_fast, end_slow = finish_times(actors.runs, timeout_s=120)
        reports, stopped = actors.reports(timeout_s=30)
        assert stopped == []
        fast, slow = (r["env_steps"] for r in reports)
        assert fast + slow == 800 == replay.info()[0].size  # exact: no step twice or lost
        assert fast >= 500 and slow >= 5 * STEPS_PER_INSERT
        # Each insert's behaviour row stands where the shared budget stood: the end of
        # the chunk it acted, so the rows of both actors are the chunk ends 4, 8, ... 800.
        at = sorted(row["run_steps"] for r in reports for row in r["behaviour_stats"])
        assert at == list(range(STEPS_PER_INSERT, 801, STEPS_PER_INSERT))
        # The fast actor claimed until the budget was spent: the slow one finished its
        # last chunk at most about one chunk later (0.16 s, plus a loaded machine's slack).
        assert end_slow - end_fast < 1.5
    finally:
        actors.kill()
        ray.kill(broadcaster)


@pytest.mark.serial  # how far an actor gets before its kill
def test_a_killed_actors_remaining_work_is_done_by_the_rest(ray_local, replay) -> None:
    actors, broadcaster = fleet(replay, 600, [0.01, 0.01])
    try:
        first = actors.slots[0]
        deadline = time.monotonic() + 60
        while first.stored < 40:  # polled by check(), as the supervisor does
            assert time.monotonic() < deadline, "actor 0 stored nothing"
            assert actors.check() == []
            time.sleep(0.05)
        ray.kill(first.actor, no_restart=True)
        ray.wait([first.run], timeout=30)
        (line,) = actors.check()
        assert "env actor 0 died" in line and "of the shared budget left to claim" in line
        assert first.stored_before >= 40 and first.incarnation == 1
        finish_times(actors.runs, timeout_s=120)
        reports, stopped = actors.reports(timeout_s=30)
        assert stopped == []
        assert sum(r["env_steps"] for r in reports) == 600  # the reported total is exact
        # Only what the dead actor stored after its last report/claim is acted twice:
        # at most the chunk in flight.
        assert 600 <= replay.info()[0].size <= 600 + STEPS_PER_INSERT
        assert reports[0]["env_steps"] > first.stored_before  # the replacement claimed too
    finally:
        actors.kill()
        ray.kill(broadcaster)
