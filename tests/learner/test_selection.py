"""The final selection: the paired rule against hand-computed cases, its settings refused
by name, and the learner loop falling back to the tree unless the policy beat it."""

from __future__ import annotations

from concurrent.futures import Future

import numpy as np
import pytest
import torch

from learner.checkpoint import load_checkpoint
from learner.loop import UNSELECTED, LoopSettings
from learner.selection import SelectionConfig, choose, corrected_z, tree_wins
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


def test_the_corrected_z_splits_one_tests_tail_among_the_candidates():
    assert corrected_z(1.645, 1) == 1.645
    assert corrected_z(1.645, 2) == pytest.approx(1.960, abs=1e-3)  # 5 % -> 2.5 % each
    assert corrected_z(1.0, 3) > corrected_z(1.0, 2) > 1.0


@pytest.mark.parametrize(
    "candidates, kept",
    [
        # both beat the tree on every episode: the higher mean is kept
        ({"policy": [105] * 4, "best": [120] * 4}, "best"),
        ({"policy": [130] * 4, "best": [120] * 4}, "policy"),
        # gains 16.5 ± 10: error √(200 / 3) / 2 ≈ 4.08; z = 4 alone asks 16.3 (passes);
        # with a second candidate each asks z' ≈ 4.16 -> 17.0 (fails)
        ({"policy": [116.5, 106.5, 126.5, 116.5]}, "policy"),
        ({"policy": [116.5, 106.5, 126.5, 116.5], "best": [90] * 4}, None),
        # the one that beats the tree is kept though the other's mean is higher
        ({"policy": [101, 101, 101, 101], "best": [200, 0, 200, 0]}, "policy"),
        ({"policy": [90] * 4, "best": [95] * 4}, None),
    ],
)
def test_choose_keeps_the_best_of_the_candidates_that_beat_the_tree(candidates, kept):
    assert choose(candidates, [100, 100, 100, 100], z=4.0) == kept


def test_choose_needs_a_candidate():
    with pytest.raises(ValueError, match="at least one candidate"):
        choose({}, [1.0, 2.0], z=1.0)


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
        self.spread, self.episodes, self.first = spread, [], []

    def evaluate(
        self, weights: Weights, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Future[Evaluation]:
        self.episodes.append(episodes)
        self.first.append(first)
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


class Peaking(FallingBack):
    """Its policy scores PEAKING[its update count]: best after 2 updates, then worse."""

    PEAKING = (0.0, 3.0, 20.0, 6.0, 5.0)

    def policy_state(self) -> Weights:
        return {"updates": torch.tensor(self.PEAKING[self.updates])}


@pytest.mark.parametrize("best_in_run", [False, True])
def test_with_best_in_run_the_loop_keeps_an_earlier_policy_that_scored_higher(
    tmp_path, best_in_run
):
    algorithm, evaluator = Peaking(tree=4.0), ScoringEvaluator(spread=0.0)
    settings = LoopSettings(
        publish_every=1, eval_every=1, eval_episodes=3, checkpoint_every=100,
        selection=SelectionConfig(episodes=4, z=1.645, best_in_run=best_in_run),
    )  # fmt: skip
    loop = one_phase_loop(tmp_path, algorithm, evaluator, updates=4, settings=settings)
    state = loop.run()
    loop.logger.close()
    published = loop.publisher.published[-1][1]
    if not best_in_run:  # the final policy (5) beat the tree (4) on every episode
        assert state.selection == {"policy": 5.0, "tree": 4.0, "tree_kept": 0.0}
        assert (algorithm.updates, published) == (4, 5.0) and evaluator.first[-2:] == [0, 0]
        assert not (tmp_path / UNSELECTED).exists()
        return
    assert state.selection == {
        "policy": 5.0, "tree": 4.0, "tree_kept": 0.0,
        "best": 20.0, "best_env_steps": 2.0, "best_kept": 1.0, "policy_alone_kept": 1.0,
    }  # fmt: skip
    assert (algorithm.updates, published, algorithm.tree_only) == (2, 20.0, False)
    # The selection plays the episodes after the in-run ones: final, best, tree.
    assert evaluator.episodes[-3:] == [4, 4, 4] and evaluator.first[-3:] == [3, 3, 3]
    [unselected] = (tmp_path / UNSELECTED).glob("ckpt-*.pt")
    assert load_checkpoint(unselected)["algorithm"] == {"updates": 4}
    [final] = (tmp_path / "checkpoints").glob("ckpt-*.pt")
    assert load_checkpoint(final)["algorithm"]["updates"] == 2
