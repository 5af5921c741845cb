"""A driver's runs on one Ray instance hand their weight broadcaster, evaluator and
environment actors on to the next run (graft/orchestration/kept.py), on a real local
Ray."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import ray
import torch
from ray.exceptions import RayActorError

from actors.evaluator import RemoteEvaluator
from graft.config import load_preset
from graft.orchestration.kept import (
    BROADCASTER,
    BUDGET,
    ENV_ACTORS,
    EVALUATOR,
    KEPT,
    KeptActors,
)
from graft.orchestration.launcher import train
from graft.orchestration.roles import probe
from service.weights import BroadcastPublisher

pytestmark = pytest.mark.service

TAG = {"env_steps": 0, "updates": 0, "wall_s": 0.0}


@ray.remote(num_cpus=0)
class _Idle:
    def ping(self) -> str:
        return "here"


def _ended(actor, within_s: float = 30.0) -> bool:
    """Whether `actor` is gone (a call fails) within `within_s`."""
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            ray.get(actor.ping.remote(), timeout=within_s)
        except RayActorError:
            return True
        time.sleep(0.05)
    return False


def _ids(actors) -> list[str]:
    return sorted(a._actor_id.hex() for a in actors)


def test_a_second_run_acts_publishes_and_evaluates_with_the_first_runs_helpers(ray_local, tmp_path):
    config = load_preset(
        "pendulum-td3",
        env_steps=300,
        learning_starts=100,
        eval_every=100,
        eval_episodes=1,
        publish_every=20,
        num_actors=2,
        **{"td3.hidden_sizes": [16, 16], "td3.batch_size": 32},
    )
    first = train(config, run_dir=tmp_path / "first", progress=False)
    roles = (BROADCASTER, EVALUATOR, ENV_ACTORS, BUDGET)
    helpers = {role: _ids(KEPT.held(role)) for role in roles}
    assert [len(ids) for ids in helpers.values()] == [1, 1, 2, 1]
    second = train(config, run_dir=tmp_path / "second", progress=False)
    for role, ids in helpers.items():  # the same actors, kept again for a third run
        assert _ids(KEPT.held(role)) == ids, role
    # Each run, the second on reset actors: updates and env steps are its own budget's
    # (a reset budget and actors count from zero), every actor that acted adopted a
    # version of that run's weights (its broadcaster publishes from version 0 again),
    # and its evaluator scored it.
    for run in (first, second):
        assert run.summary["updates"] == 200 and run.summary["env_steps"] == 300
        assert sum(run.summary["actor_env_steps"]) == 300
        steps, adopted = run.summary["actor_env_steps"], run.summary["actor_versions_adopted"]
        assert all(v >= 1 for n, v in zip(steps, adopted, strict=True) if n), run.summary
        assert max(run.summary["actor_last_version"]) <= run.summary["policy_version"]
        assert len(run.evaluations) >= 3 and np.isfinite(run.summary["final_eval_return_mean"])


def test_an_actor_no_run_takes_is_ended_after_keep_s(ray_local):
    kept = KeptActors(keep_s=0.2)
    actor = _Idle.remote()
    kept.keep("helper", "a", actor)
    assert kept.held("helper") == [actor]
    assert _ended(actor)
    assert kept.held("helper") == [] and kept.take("helper", "a") is None


@ray.remote(num_cpus=0, runtime_env={"env_vars": {"GRAFT_TEST_FRESH_WORKER": "kept"}})
def _a_run_in_a_task() -> int:
    """As a run inside a Ray task leaves things: an actor kept, its handle also held by a
    reference cycle of the run's objects. The task's worker (its own: a runtime
    environment no other task has) pid."""
    kept = KeptActors(keep_s=0.3)
    run: dict = {"actor": _Idle.remote()}
    run["self"] = run
    kept.keep("helper", "a", run["actor"])
    return os.getpid()


def test_a_task_worker_whose_kept_actors_ended_is_ended_too(ray_local):
    import psutil  # Ray's vendored copy, importable once Ray is

    pid = ray.get(_a_run_in_a_task.remote())
    deadline = time.monotonic() + 30.0
    while psutil.pid_exists(pid) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not psutil.pid_exists(pid), "the worker stayed, holding the ended actor's handle"


def test_of_several_kept_actors_those_no_run_takes_are_ended(ray_local):
    kept = KeptActors(keep_s=1.0)
    actors = [_Idle.remote() for _ in range(3)]
    kept.keep("workers", "a", *actors)
    taken = kept.take("workers", "a")
    assert taken in actors and len(kept.held("workers")) == 2
    assert all(_ended(a) for a in actors if a is not taken)
    assert ray.get(taken.ping.remote()) == "here" and kept.held("workers") == []
    ray.kill(taken)


def test_a_run_asking_for_another_key_ends_the_kept_actor(ray_local):
    kept = KeptActors(keep_s=60.0)
    fits, other = _Idle.remote(), _Idle.remote()
    kept.keep("helper", "a", fits)
    assert kept.take("helper", "a") is fits  # taken: no longer kept, and not ended
    assert ray.get(fits.ping.remote()) == "here"
    kept.keep("helper", "a", other)
    assert kept.take("helper", "b") is None
    assert _ended(other)
    assert ray.get(fits.ping.remote()) == "here"
    ray.kill(fits)


def test_a_kept_broadcaster_starts_over_for_its_next_run(ray_local):
    old = BroadcastPublisher()
    old.publish(5, {"w": torch.zeros(1)})
    old.stop()
    new = BroadcastPublisher(kept=old.release())
    assert new.broadcaster._actor_id == old.broadcaster._actor_id
    new.publish(0, {"w": torch.ones(1)})  # version 0 again: no "not newer" refusal
    subscriber = new.subscriber()
    weights = subscriber.poll(block_s=30.0)
    assert not subscriber.stopped and subscriber.version == 0
    assert np.array_equal(weights["w"], np.ones(1))
    new.close()


def test_a_dead_kept_evaluator_is_replaced_by_a_new_one(ray_local):
    builder, _, _ = probe(load_preset("pendulum-td3", **{"td3.hidden_sizes": [8, 8]}))
    weights = builder.make_learner().policy_state()
    args = {"env": load_preset("pendulum-td3").env_spec(), "seed": 3}
    first = RemoteEvaluator(behaviour=builder.make_behaviour(num_actors=1), **args)
    scored = first.evaluate(weights, episodes=1, tag=TAG).result(timeout=120)
    dead = first.release()
    ray.kill(dead)
    second = RemoteEvaluator(behaviour=builder.make_behaviour(num_actors=1), kept=dead, **args)
    try:
        again = second.evaluate(weights, episodes=1, tag=TAG).result(timeout=120)
    finally:
        second.close()
    assert second.restarts == 0 and again["returns"] == scored["returns"]
