"""The learner does not hang on a dead actor: the watchdog raises the actor's error."""

from __future__ import annotations

import pytest
import ray

from graft.orchestration.progress import check_actors


@ray.remote
def crashed_actor_run() -> None:
    raise ValueError("env exploded at step 12")


@ray.remote
def finished_actor_run() -> dict:
    return {"env_steps": 10}


def test_a_crashed_actor_surfaces_its_error(ray_local):
    refs = [crashed_actor_run.remote(), finished_actor_run.remote()]
    ray.wait(refs, num_returns=2)
    with pytest.raises(ValueError, match="env exploded at step 12"):
        check_actors(refs)


def test_all_actors_done_but_learner_waiting_is_an_error(ray_local):
    refs = [finished_actor_run.remote()]
    ray.wait(refs)
    with pytest.raises(RuntimeError, match="still waiting for sampled batches"):
        check_actors(refs)
