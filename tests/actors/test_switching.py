"""Value-based switching between the tree μ and the learned policy, and the tree-only flag
the final selection publishes: the rule against hand-computed cases, then each behaviour
(backbone TD3's, Double DQN's) acting it with critics whose values are fixed by hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from actors.behaviours.backbone import BackboneBehaviour
from actors.behaviours.epsilon_greedy import EpsilonGreedyBehaviour
from actors.behaviours.switching import TREE_ONLY, check_margin, split_weights, switch_mask
from learner.selection import with_tree_only
from service.core import WeightArrays, as_arrays
from tests.learner.helpers import FixedRows

TREE_KEPT = {TREE_ONLY: np.array(1.0, np.float32)}
"""What a learner that kept the tree adds to its published weights (as actors get them)."""


@pytest.mark.parametrize(
    "q_tree, q_policy, margin, expected",
    [
        (10.0, 10.5, 0.0, True),  # any gain, margin 0
        (10.0, 10.0, 0.0, False),  # a tie keeps the tree
        (10.0, 10.5, 0.1, False),  # 10.5 ≤ 10 + 0.1·10 = 11
        (10.0, 11.5, 0.1, True),
        (-10.0, -9.5, 0.1, False),  # −9.5 ≤ −10 + 0.1·10 = −9
        (-10.0, -8.5, 0.1, True),
        (0.0, 1e-6, 0.5, True),  # |Q(s, μ)| = 0: any gain
    ],
)
def test_switch_mask_matches_hand_computed_cases(q_tree, q_policy, margin, expected):
    assert switch_mask(np.array([q_tree]), np.array([q_policy]), margin).tolist() == [expected]


def test_bad_margins_are_refused_by_name():
    check_margin("switch_margin", None)
    check_margin("switch_margin", 0.0)
    with pytest.raises(ValueError, match=r"switch_margin=-0.1 must be >= 0"):
        check_margin("switch_margin", -0.1)
    with pytest.raises(ValueError, match=r"switch_margin=nan"):
        check_margin("switch_margin", float("nan"))


def test_published_weights_split_into_policy_critic_and_tree_only_flag():
    w = {"net.w": torch.ones(1), "critic.q1.w": torch.zeros(1)}
    policy, critic, tree_only = split_weights(as_arrays(w))
    assert (set(policy), set(critic), tree_only) == ({"net.w"}, {"q1.w"}, False)
    assert with_tree_only(w, False) is w  # nothing added unless the tree is kept
    kept = as_arrays(with_tree_only(w, True))  # published: numpy arrays
    assert split_weights(kept)[2] is True and TREE_ONLY not in split_weights(kept)[0]


class LinearTwin:
    """A twin critic Q_i(x, c) = a_i · c (one action dimension) as actors hold one (numpy,
    the smaller estimate): the value of a correction c is set by hand; Q(x, 0) = 0 is the
    tree's. `load` takes {"a": [a1, a2]}."""

    def __init__(self, a1: float, a2: float) -> None:
        self.a = np.array([a1, a2], np.float32)

    def load(self, weights: WeightArrays) -> None:
        self.a = np.asarray(weights["a"], np.float32)

    def __call__(self, obs: np.ndarray, act: np.ndarray) -> np.ndarray:
        return np.minimum(self.a[0] * act[:, 0], self.a[1] * act[:, 0])


def _backbone(critic: LinearTwin, correction: float, margin: float = 0.0) -> BackboneBehaviour:
    """μ(s) = 0.5 on a box [−2, 2]; π(s) = `correction` everywhere."""
    return BackboneBehaviour(
        FixedRows([[correction]]),
        lambda obs: np.full((len(obs), 1), 0.5, np.float32),
        limit=1.0,
        std=0.1,
        prefill_std=0.1,
        low=np.array([-2.0]),
        high=np.array([2.0]),
        critic=critic,  # type: ignore[arg-type]
        switch_margin=margin,
    )


@pytest.mark.parametrize(
    "a1, a2, correction, expected",
    [
        (1.0, 1.0, 0.4, 0.9),  # both critics value +0.4 above 0: π acts, 0.5 + 0.4
        (1.0, -1.0, 0.4, 0.5),  # the smaller twin says −0.4 < 0: the tree
        (-1.0, -1.0, -0.4, 0.1),  # −0.4·−1 = +0.4 on both: π acts, 0.5 − 0.4
        (2.0, 1.0, 0.0, 0.5),  # no correction: the tree either way
    ],
)
def test_backbone_greedy_acts_pi_only_where_the_smaller_critic_values_it_above_the_tree(
    a1, a2, correction, expected
):
    behaviour = _backbone(LinearTwin(a1, a2), correction)
    np.testing.assert_allclose(behaviour.greedy(np.zeros((3, 2), np.float32)), [[expected]] * 3)


def test_backbone_switching_reads_the_published_critic_and_the_tree_only_flag():
    behaviour = _backbone(LinearTwin(-1.0, -1.0), 0.4)
    obs = np.zeros((2, 2), np.float32)
    published = {"critic.a": np.array([1.0, 1.0]), "rows": np.array([[0.4]])}
    behaviour.load(published)
    np.testing.assert_allclose(behaviour.greedy(obs), [[0.9]] * 2)  # the new critic says +
    assert behaviour.stats() == {"switch/policy_share": 1.0}
    behaviour.load({**published, **TREE_KEPT})
    np.testing.assert_allclose(behaviour.greedy(obs), [[0.5]] * 2)  # the tree alone
    # Exploration ignores both: it acts around μ + π to learn about π's actions.
    _, columns = behaviour.act(obs, np.random.default_rng(0), warmup=False)
    assert np.abs(columns["action"] - 0.4).max() < 0.5


@pytest.mark.parametrize(
    "a1, a2, correction, around",
    [
        (1.0, 1.0, 0.4, 0.9),  # the critic values π's +0.4 above the tree's 0: around μ + π
        (1.0, -1.0, 0.4, 0.5),  # the smaller twin says −0.4 < 0: around the tree μ
        (-1.0, -1.0, -0.4, 0.1),  # +0.4 on both: around μ + π = 0.1
        (1.0, 1.0, -0.4, 0.5),  # −0.4 < 0: the tree
    ],
)
def test_backbone_exploration_acts_around_the_proposal_the_critic_values_higher(
    a1, a2, correction, around
):
    behaviour = BackboneBehaviour(
        FixedRows([[correction]]),
        lambda obs: np.full((len(obs), 1), 0.5, np.float32),
        limit=1.0,
        std=0.01,
        prefill_std=0.1,
        low=np.array([-2.0]),
        high=np.array([2.0]),
        critic=LinearTwin(a1, a2),  # type: ignore[arg-type]
        propose_tree=True,
    )
    obs = np.zeros((200, 2), np.float32)
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=False)
    assert abs(float(action.mean()) - around) < 0.01 and 0.005 < float(action.std()) < 0.02
    np.testing.assert_allclose(columns["action"], action - 0.5, atol=1e-6)  # the correction
    # The prefill ignores it (π is not trained yet), and the greedy policy (no switching
    # margin) is π's: the choice is exploration's.
    prefill, _ = behaviour.act(obs, np.random.default_rng(0), warmup=True)
    assert abs(float(prefill.mean()) - 0.5) < 0.03
    np.testing.assert_allclose(behaviour.greedy(obs[:2]), [[0.5 + correction]] * 2, atol=1e-6)


def test_backbone_switching_needs_a_critic_and_a_margin():
    with pytest.raises(ValueError, match="switching and propose_tree need a critic"):
        BackboneBehaviour(
            FixedRows([[0.0]]),
            lambda obs: obs,
            limit=1.0,
            std=0.1,
            prefill_std=0.1,
            low=np.array([-1.0]),
            high=np.array([1.0]),
            propose_tree=True,
        )
    with pytest.raises(ValueError, match="used by switching .switch_margin. or propose_tree"):
        BackboneBehaviour(
            FixedRows([[0.0]]),
            lambda obs: obs,
            limit=1.0,
            std=0.1,
            prefill_std=0.1,
            low=np.array([-1.0]),
            high=np.array([1.0]),
            critic=LinearTwin(1.0, 1.0),  # type: ignore[arg-type]
        )


def _dqn(q_row: list[float], margin, mu: int = 0) -> EpsilonGreedyBehaviour:
    return EpsilonGreedyBehaviour(
        FixedRows([q_row]),
        epsilon_start=0.1,
        epsilon_end=0.1,
        decay_env_steps=1,
        num_actors=1,
        hardcoded=lambda obs: np.full(len(obs), mu, np.int64),
        switch_margin=margin,
    )


@pytest.mark.parametrize(
    "q_row, margin, expected",
    [
        ([10.0, 10.5, 9.0], None, 1),  # plain argmax
        ([10.0, 10.5, 9.0], 0.0, 1),  # 10.5 > 10
        ([10.0, 10.5, 9.0], 0.1, 0),  # 10.5 ≤ 10 + 1: the tree's 0
        ([10.0, 11.5, 9.0], 0.1, 1),
        ([10.0, 9.0, 8.0], 0.0, 0),  # the tree's action is Q's best
    ],
)
def test_dqn_greedy_takes_qs_best_action_only_where_it_beats_the_trees(q_row, margin, expected):
    behaviour = _dqn(q_row, margin)
    assert behaviour.greedy(np.zeros((2, 3), np.float32)).tolist() == [expected] * 2


def test_dqn_tree_only_flag_makes_the_greedy_policy_the_tree():
    behaviour = _dqn([0.0, 5.0], None, mu=0)
    behaviour.load({"rows": np.array([[0.0, 5.0]]), **TREE_KEPT})
    assert behaviour.greedy(np.zeros((3, 2), np.float32)).tolist() == [0, 0, 0]
    with pytest.raises(ValueError, match="needs a hard-coded policy"):
        EpsilonGreedyBehaviour(
            FixedRows([[0.0]]),
            epsilon_start=0.1,
            epsilon_end=0.1,
            decay_env_steps=1,
            num_actors=1,
            switch_margin=0.0,
        )
