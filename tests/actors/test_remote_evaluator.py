"""The run's evaluator (a Ray actor): a world lost in an evaluation is a fault it restarts
from; any other error is the run's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from ray.exceptions import RayTaskError

from actors.evaluator import RemoteEvaluator
from actors.task import EnvSpec
from graft.config import load_preset
from graft.orchestration.roles import probe

WORLDS = Path(__file__).resolve().parents[1] / "fixtures" / "worlds"
TAG = {"env_steps": 0, "updates": 0, "wall_s": 0.0}


def _evaluator(marker: Path, said: list[str], max_restarts: int) -> tuple[RemoteEvaluator, dict]:
    config = load_preset("pendulum-td3", **{"td3.hidden_sizes": [8, 8]})
    builder, _, _ = probe(config)
    weights = builder.make_learner().policy_state()
    env = EnvSpec("flaky_world:FlakyWorld", {"marker": str(marker)}, import_path=(str(WORLDS),))
    evaluator = RemoteEvaluator(
        env=env,
        behaviour=builder.make_behaviour(num_actors=1),
        seed=7,
        max_restarts=max_restarts,
        on_restart=said.append,
    )
    return evaluator, weights


@pytest.mark.service
def test_a_lost_world_restarts_the_evaluator_and_the_same_episodes_play(ray_local, tmp_path):
    said: list[str] = []
    evaluator, weights = _evaluator(tmp_path / "gone", said, max_restarts=1)
    try:
        clean = evaluator.evaluate(weights, episodes=2, tag=TAG).result(timeout=120)
        (tmp_path / "gone").touch()  # the world goes away in the next evaluation
        again = evaluator.evaluate(weights, episodes=2, tag=TAG).result(timeout=120)
    finally:
        evaluator.close()
    assert evaluator.restarts == 1 and not (tmp_path / "gone").exists()
    assert said == [
        "evaluator lost its world (connection closed after 0 of 4 bytes); "
        "restarted it (evaluator restart 1)"
    ]
    np.testing.assert_array_equal(again["returns"], clean["returns"])  # seeded episodes


@pytest.mark.service
def test_without_restarts_left_a_lost_world_fails_the_evaluation(ray_local, tmp_path):
    (tmp_path / "gone").touch()
    evaluator, weights = _evaluator(tmp_path / "gone", [], max_restarts=0)
    try:
        lost = r"^the evaluator lost its world \(connection closed after 0 of 4 bytes\)"
        with pytest.raises(RuntimeError, match=lost + " after 0 restarts"):
            evaluator.evaluate(weights, episodes=1, tag=TAG).result(timeout=120)
    finally:
        evaluator.close()


@pytest.mark.service
def test_another_error_of_an_evaluation_is_not_retried(ray_local, tmp_path):
    said: list[str] = []
    evaluator, weights = _evaluator(tmp_path / "gone", said, max_restarts=3)
    try:
        with pytest.raises(RayTaskError):  # no episodes: refused in the actor, every time
            evaluator.evaluate(weights, episodes=0, tag=TAG).result(timeout=120)
    finally:
        evaluator.close()
    assert evaluator.restarts == 0 and said == []
