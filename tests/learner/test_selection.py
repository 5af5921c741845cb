"""The final selection: the paired rule against hand-computed cases, its settings refused
by name, and the learner loop falling back to the tree unless the policy beat it."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest
import torch

from learner.loop import LoopSettings
from learner.selection import SelectionConfig, tree_wins
from service.core import EvalTag, Evaluation, Weights
from service.metrics import read_metric
from tests.learner.test_loop import CountingAlgorithm, one_phase_loop


@pytest.mark.parametrize(
    "policy, tree, z, kept",
    [
        ([105, 105], [100, 100], 1.0, False),  # the same gain on every episode
        ([100, 100], [100, 100], 1.0, True),  # a tie keeps the tree
        # gains 10 on every start: kept, however much the starts' returns vary
        ([110, 90, 130, 70], [100, 80, 120, 60], 1.0, False),
        # gains 10, −10, 30, −10: mean 5, std √(1100 / 3) ≈ 19.15, error ≈ 9.57 > 5
        ([110, 90, 130, 70], [100, 100, 100, 80], 1.0, True),
        ([110, 90, 130, 70], [100, 100, 100, 80], 0.0, False),  # z = 0: any mean gain
        # gains 20, 10, 30, 20: mean 20, error √(200 / 3) / 2 ≈ 4.08; z = 5 asks 20.4
        ([120, 110, 130, 120], [100, 100, 100, 100], 1.0, False),
        ([120, 110, 130, 120], [100, 100, 100, 100], 5.0, True),
        ([90, 90], [100, 100], 0.0, True),
    ],
)
def test_tree_wins_matches_hand_computed_cases(policy, tree, z, kept):
    assert tree_wins(policy, tree, z=z) is kept


def test_tree_wins_needs_the_same_episodes_for_both():
    with pytest.raises(ValueError, match="same >= 2 episodes for both, got 3 and 2"):
        tree_wins([1.0, 2.0, 3.0], [1.0, 2.0], z=1.0)
    with pytest.raises(ValueError, match="got 1 and 1"):
        tree_wins([1.0], [1.0], z=1.0)


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
        self.tree, self.tree_only = tree, False

    @property
    def kept(self) -> bool:
        return self.tree_only

    def tree_state(self) -> Weights:
        return {"updates": torch.tensor(self.tree), "tree": torch.tensor(1.0)}

    def keep_tree(self) -> None:
        self.tree_only = True


class ScoringEvaluator:
    """Every episode returns the weights' "updates"; the tree's alternate ± `spread` around
    it. Records episode counts."""

    def __init__(self, spread: float) -> None:
        self.spread, self.episodes = spread, []

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Future[Evaluation]:
        self.episodes.append(episodes)
        spread = self.spread if "tree" in weights else 0.0
        returns = [float(weights["updates"]) + spread * (-1) ** i for i in range(episodes)]
        future: Future[Evaluation] = Future()
        mean = float(np.mean(returns))
        future.set_result({"tag": tag, "mean": mean, "std": 0.0, "stats": {}, "returns": returns})
        return future


@pytest.mark.parametrize(
    "tree, spread, episodes, kept",
    [
        (10.0, 0.0, 4, True),  # the policy scores 4 (its updates) < 10
        (1.0, 0.0, 4, False),  # 4 > 1 on every episode
        (1.0, 6.0, 4, True),  # gains −3, 9, −3, 9: mean 3 ≤ √48 / 2 ≈ 3.46
        (1.0, 6.0, 0, False),  # no selection at all
    ],
)
def test_the_loop_keeps_the_tree_unless_the_policy_beat_it(tmp_path, tree, spread, episodes, kept):
    algorithm, evaluator = FallingBack(tree), ScoringEvaluator(spread)
    settings = LoopSettings(
        publish_every=2,
        eval_every=100,
        eval_episodes=1,
        checkpoint_every=5,
        selection=SelectionConfig(episodes=episodes),
    )
    loop = one_phase_loop(tmp_path, algorithm, evaluator, updates=4, settings=settings)
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
