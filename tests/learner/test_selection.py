"""The final selection: the rule against hand-computed cases, its settings refused by
name, and the learner loop falling back to the tree when the tree scores higher."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest
import torch

from learner.agent import Phase
from learner.loop import LearnerLoop, LoopSettings
from learner.selection import SelectionConfig, tree_wins
from service.core import EvalTag, Evaluation, Weights
from service.metrics import MetricsLogger, read_metric
from tests.learner.test_loop import CountingAlgorithm, ListStream, RecordingPublisher, batches


@pytest.mark.parametrize(
    "policy, tree, stds, n, z, kept",
    [
        (105.0, 100.0, (0.0, 0.0), 10, 1.0, False),  # no spread: any gain keeps the policy
        (100.0, 100.0, (0.0, 0.0), 10, 1.0, True),  # a tie keeps the tree
        # error √((30² + 40²) / 25) = 10: a gain of 10 is not above 1 error, 10.1 is
        (110.0, 100.0, (30.0, 40.0), 25, 1.0, True),
        (110.1, 100.0, (30.0, 40.0), 25, 1.0, False),
        (115.0, 100.0, (30.0, 40.0), 25, 2.0, True),  # 15 ≤ 2 · 10
        (100.1, 100.0, (30.0, 40.0), 25, 0.0, False),  # z = 0: any gain
        (90.0, 100.0, (0.0, 0.0), 10, 0.0, True),
    ],
)
def test_tree_wins_matches_hand_computed_cases(policy, tree, stds, n, z, kept):
    result = tree_wins(
        policy_mean=policy, policy_std=stds[0], tree_mean=tree, tree_std=stds[1], episodes=n, z=z
    )
    assert result is kept


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"episodes": -1}, "episodes=-1 must be >= 0"),
        ({"episodes": 1}, "episodes=1 gives no spread"),
        ({"z": -0.5}, "z=-0.5 must be a finite number >= 0"),
        ({"z": float("inf")}, "z=inf must be a finite number"),
    ],
)
def test_bad_selection_settings_are_refused_by_name(fields, message):
    with pytest.raises(ValueError, match=message):
        SelectionConfig(**fields)


class FallingBack(CountingAlgorithm):
    """Its policy scores its update count; the tree alone scores `tree`."""

    def __init__(self, tree: float) -> None:
        super().__init__()
        self.tree, self.kept = tree, False

    def tree_state(self) -> Weights:
        return {"updates": torch.tensor(self.tree)}

    def keep_tree(self) -> None:
        self.kept = True


class ScoringEvaluator:
    """The return is the weights' "updates", with a fixed spread; records episode counts."""

    def __init__(self, std: float) -> None:
        self.std, self.episodes = std, []

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Future[Evaluation]:
        self.episodes.append(episodes)
        future: Future[Evaluation] = Future()
        future.set_result(
            {"tag": tag, "mean": float(weights["updates"]), "std": self.std, "stats": {}}
        )
        return future


@pytest.mark.parametrize(
    "tree, std, episodes, kept",
    [
        (10.0, 0.0, 4, True),  # the policy scores 4 (its updates) < 10
        (1.0, 0.0, 4, False),  # 4 > 1
        (1.0, 6.0, 4, True),  # 3 ≤ √((36 + 36) / 4) ≈ 4.2
        (1.0, 6.0, 0, False),  # no selection at all
    ],
)
def test_the_loop_keeps_the_tree_unless_the_policy_beat_it(tmp_path, tree, std, episodes, kept):
    algorithm, evaluator = FallingBack(tree), ScoringEvaluator(std)
    loop = LearnerLoop(
        algorithm,
        phases=[Phase("online", env_steps=0, updates=4, min_size=1)],
        open_stream=lambda phase: ListStream(batches(0, 4)),
        publisher=RecordingPublisher(),
        evaluator=evaluator,
        logger=MetricsLogger(tmp_path, tensorboard=False),
        checkpoint_dir=tmp_path / "checkpoints",
        settings=LoopSettings(
            publish_every=2,
            eval_every=100,
            eval_episodes=1,
            checkpoint_every=5,
            selection=SelectionConfig(episodes=episodes),
        ),
    )
    state = loop.run()
    loop.logger.close()
    assert algorithm.kept is kept
    if not episodes:
        assert state.selection == {} and evaluator.episodes == [1]
        return
    assert evaluator.episodes == [1, episodes, episodes]  # the final evaluation, then both
    assert state.selection == {"policy": 4.0, "tree": tree, "tree_kept": float(kept)}
    _, values = read_metric(tmp_path / "metrics.csv", "select/tree_kept")
    np.testing.assert_allclose(values, [float(kept)])
