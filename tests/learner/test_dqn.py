"""Double DQN (learner/dqn) and its ε-greedy behaviour: targets against hand-computed values, the
target network and the learning-rate schedule."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch

from actors.behaviours.epsilon_greedy import (
    EpsilonGreedyBehaviour,
    epsilon_greedy,
    linear_epsilon,
)
from actors.behaviours.switching import TREE_ONLY
from learner.dqn.config import DQNConfig
from learner.dqn.learning import (
    DQNLearner,
    double_q_target,
    large_margin_loss,
    linear_decay,
    margin_weight,
)
from learner.dqn.networks import make_q_network
from learner.td3.networks import acting_copy
from tests.learner.helpers import Table


def test_double_dqn_target_lets_the_online_net_choose_and_the_target_net_value():
    online = Table([[1.0, 3.0], [5.0, 2.0]])  # argmax: action 1, then action 0
    target = Table([[10.0, 20.0], [30.0, 40.0]])
    reward = torch.tensor([1.0, 2.0])
    discount = 0.9 * (1.0 - torch.tensor([0.0, 1.0]))  # second s' is terminal
    y = double_q_target(reward, discount, torch.zeros(2, 4), online=online, target=target)
    # 1 + 0.9 * Q_target(s', 1) = 1 + 18; terminal: just r. (Plain DQN would take 40 for row 2.)
    torch.testing.assert_close(y, torch.tensor([19.0, 2.0]))


def test_epsilon_greedy_log_likelihoods_and_schedule():
    q = np.array([[0.0, 1.0, 0.0]] * 4000)
    action, log_prob = epsilon_greedy(q, 0.3, np.random.default_rng(0))
    greedy = action == 1
    np.testing.assert_allclose(log_prob[greedy], math.log(0.7 + 0.1), rtol=1e-6)
    np.testing.assert_allclose(log_prob[~greedy], math.log(0.1), rtol=1e-6)
    assert abs(greedy.mean() - 0.8) < 0.03
    assert linear_epsilon(500, start=1.0, end=0.1, decay_steps=1000) == pytest.approx(0.55)
    assert linear_epsilon(5000, start=1.0, end=0.1, decay_steps=1000) == pytest.approx(0.1)


def _dqn_batch() -> dict[str, torch.Tensor]:
    """8 identical transitions of a 2-feature, 2-action task: action 0, reward 1."""
    return {
        "obs": torch.ones(8, 2),
        "action": torch.zeros(8, dtype=torch.int64),
        "reward": torch.ones(8),
        "terminated": torch.zeros(8, dtype=torch.bool),
        "next_obs": torch.ones(8, 2),
    }


@pytest.mark.parametrize("tau, moved", [(1.0, 1.0), (0.25, 0.25)])
def test_dqn_target_network_moves_every_target_update_every_updates(tau, moved):
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner

    learner = DQNLearner(
        2, 2, config=DQNConfig(hidden_sizes=(4,), target_update_every=3, target_tau=tau), seed=0
    )
    before = [p.clone() for p in learner.target_q.parameters()]
    batch = _dqn_batch()
    for _ in range(2):
        learner.update(batch)
    assert all(
        torch.equal(a, b) for a, b in zip(before, learner.target_q.parameters(), strict=True)
    )
    learner.update(batch)  # the third update moves the target a `tau` step towards online
    for old, new, online in zip(
        before, learner.target_q.parameters(), learner.q.parameters(), strict=True
    ):
        torch.testing.assert_close(new, old + moved * (online - old))


@pytest.mark.parametrize(
    "step, expected",
    [(0, 4e-3), (1, 3e-3), (2, 2e-3), (3, 1e-3), (4, 0.0), (9, 0.0)],  # 4e-3 · (1 − step/4)
)
def test_learning_rate_decays_linearly_to_its_end_value_and_stays(step, expected):
    assert linear_decay(4e-3, 0.0, step=step, steps=4) == pytest.approx(expected)


def test_dqn_learner_steps_at_the_scheduled_rate_and_stops_moving_at_zero():
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner

    config = DQNConfig(hidden_sizes=(4,), learning_rate=4e-3, learning_rate_end=0.0)
    learner = DQNLearner(2, 2, config=config, seed=0, total_updates=4)
    batch = _dqn_batch()
    rates = [learner.update(batch)["charts/learning_rate"] for _ in range(4)]
    assert rates == pytest.approx([4e-3, 3e-3, 2e-3, 1e-3])
    # Past the schedule the rate is 0: Adam's step is lr-scaled, so the network is frozen.
    before = [p.clone() for p in learner.q.parameters()]
    assert learner.update(batch)["charts/learning_rate"] == 0.0
    assert all(torch.equal(a, b) for a, b in zip(before, learner.q.parameters(), strict=True))
    # A resumed learner continues the schedule from its update count.
    resumed = DQNLearner(2, 2, config=config, seed=1, total_updates=4)
    learner.num_updates = 2
    resumed.load_state_dict(learner.state_dict())
    assert resumed.learning_rate == pytest.approx(2e-3)


def test_dqn_learning_rate_schedule_refuses_what_cannot_decay():
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner

    for end in (-1e-4, 2e-3):  # below 0, above the start rate
        with pytest.raises(ValueError, match="learning_rate_end"):
            DQNConfig(learning_rate=1e-3, learning_rate_end=end)
    with pytest.raises(ValueError, match="total_updates"):
        DQNLearner(2, 2, config=DQNConfig(learning_rate_end=0.0), seed=0)
    # Without an end value the rate is constant, whatever the update count.
    learner = DQNLearner(2, 2, config=DQNConfig(learning_rate=1e-3), seed=0)
    learner.num_updates = 10**6
    assert learner.learning_rate == 1e-3


def test_dqn_builder_decays_the_rate_over_the_runs_updates():
    from gymnasium import spaces

    from learner.agent import Budget
    from learner.dqn.builder import DQNBuilder
    from learner.dqn.config import DQNConfig

    builder = DQNBuilder(
        spaces.Box(-1.0, 1.0, shape=(4,)),
        spaces.Discrete(2),
        config=DQNConfig(hidden_sizes=(4,), learning_rate=1e-3, learning_rate_end=1e-4),
        budget=Budget(
            env_steps=5000, learning_starts=1000, updates_per_env_step=0.5, slack_env_steps=0
        ),
        seed=0,
    )
    learner = builder.make_learner()
    learner.num_updates = 1000  # half of (5000 − 1000) · 0.5 = 2000 updates
    assert learner.learning_rate == pytest.approx(5.5e-4)
    learner.num_updates = 2000
    assert learner.learning_rate == pytest.approx(1e-4)


# Demonstrations of a hard-coded policy (dqn.warmup: hardcoded): DQfD's large-margin loss.
MARGIN_CASES = [
    # Q(s, ·), a_E, margin, loss = max_a [Q(s, a) + l(a_E, a)] − Q(s, a_E)
    ([[1.0, 3.0, 0.0]], [1], 0.8, 0.0),  # a_E ahead by 1 ≥ 0.8: nothing to push
    ([[1.0, 1.5, 0.0]], [1], 0.8, 0.3),  # ahead by 0.5 only: 1 + 0.8 − 1.5
    ([[2.0, 1.0, 0.0]], [1], 0.8, 1.8),  # another action ahead: 2 + 0.8 − 1
    ([[2.0, 1.0, 0.0], [1.0, 3.0, 0.0]], [1, 1], 0.8, 0.9),  # mean of 1.8 and 0
    ([[2.0, 1.0, 0.0]], [1], 0.0, 1.0),  # margin 0: the plain ranking gap
]


@pytest.mark.parametrize("q, expert, margin, expected", MARGIN_CASES)
def test_large_margin_loss_by_hand(q, expert, margin, expected):
    loss = large_margin_loss(torch.tensor(q), torch.tensor(expert), margin)
    assert float(loss) == pytest.approx(expected)


def test_large_margin_loss_over_the_rows_kept():
    # Rows 1.8, 0 and 0.3 (see MARGIN_CASES); the middle one is padding: (1.8 + 0.3) / 2.
    q = torch.tensor([[2.0, 1.0, 0.0], [1.0, 3.0, 0.0], [1.0, 1.5, 0.0]])
    weight = torch.tensor([1.0, 0.0, 1.0])
    loss = large_margin_loss(q, torch.tensor([1, 1, 1]), 0.8, weight)
    assert float(loss) == pytest.approx(1.05)


def _demo_batch(n: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """Demonstrations of μ(s) = 1 if s_1 > 0 else 0 on 2-feature states, reward 0."""
    obs = rng.normal(size=(n, 2)).astype(np.float32)
    mu = (obs[:, 1] > 0).astype(np.int64)
    return {
        "obs": torch.as_tensor(obs),
        "action": torch.as_tensor(mu),
        "backbone_action": torch.as_tensor(mu),
        "reward": torch.zeros(n),
        "terminated": torch.zeros(n, dtype=torch.bool),
        "next_obs": torch.as_tensor(obs),
    }


def test_burn_in_with_the_margin_loss_makes_the_greedy_policy_the_hard_coded_one():
    config = DQNConfig(hidden_sizes=(16,), warmup="hardcoded", burn_in_updates=200)
    learner = DQNLearner(2, 2, config=config, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(200):
        metrics = learner.update(_demo_batch(64, rng))
        assert "losses/margin" in metrics
    test = _demo_batch(1000, rng)
    greedy = learner.q(test["obs"]).argmax(dim=1)
    # TD alone gives no reason to prefer μ's action (every reward is 0): the margin does.
    assert float((greedy == test["backbone_action"]).float().mean()) > 0.95
    # After the burn-in: plain Double DQN, the recorded μ(s) is not needed.
    batch = _demo_batch(64, rng)
    del batch["backbone_action"]
    assert "losses/margin" not in learner.update(batch)


def test_uniform_warmup_never_adds_the_margin_loss():
    learner = DQNLearner(2, 2, config=DQNConfig(hidden_sizes=(16,), burn_in_updates=5), seed=0)
    batch = _demo_batch(8, np.random.default_rng(0))
    assert "losses/margin" not in learner.update(batch)


def test_demonstrations_act_epsilon_greedily_around_the_hard_coded_policy():
    def mu(obs: np.ndarray) -> np.ndarray:
        return (obs[:, 1] > 0).astype(np.int64)

    behaviour = EpsilonGreedyBehaviour(
        acting_copy(make_q_network(2, 3, ())),  # Q(s, ·) over three actions, unused in warm-up
        epsilon_start=1.0,
        epsilon_end=0.05,
        decay_env_steps=10,
        num_actors=1,
        hardcoded=mu,
        demo_epsilon=0.3,
    )
    assert behaviour.columns()["backbone_action"] == {"dtype": "int64", "shape": []}
    obs = np.random.default_rng(1).normal(size=(4000, 2)).astype(np.float32)
    action, columns = behaviour.act(obs, np.random.default_rng(2), warmup=True)
    np.testing.assert_array_equal(columns["backbone_action"], mu(obs))
    followed = action == mu(obs)
    assert abs(followed.mean() - (0.7 + 0.3 / 3)) < 0.03  # 1 − ε + ε/n
    np.testing.assert_allclose(columns["log_prob"][followed], math.log(0.8), rtol=1e-6)
    np.testing.assert_allclose(columns["log_prob"][~followed], math.log(0.1), rtol=1e-6)
    # Online: the Q network's ε-greedy (ε from epsilon_start), μ(s) still recorded.
    _, online = behaviour.act(obs[:5], np.random.default_rng(3), warmup=False)
    np.testing.assert_array_equal(online["backbone_action"], mu(obs[:5]))


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("warmup", "expert", "warmup='expert' must be one of uniform, hardcoded"),
        ("demo_epsilon", 0.0, "demo_epsilon=0.0 must lie in (0, 1]"),
        ("burn_in_updates", -1, "burn_in_updates=-1 must be >= 0"),
        ("margin", -0.1, "margin=-0.1 must be >= 0"),
        ("switch_margin", -0.1, "switch_margin=-0.1 must be >= 0"),
    ],
)
def test_dqn_demonstration_settings_are_refused_by_name(field, value, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        DQNConfig(**{field: value})


@pytest.mark.parametrize("field, value", [("switch_margin", 0.0), ("margin_after_burn_in", True)])
def test_comparing_with_the_tree_needs_the_trees_demonstrations(field, value):
    with pytest.raises(ValueError, match="need dqn.warmup: hardcoded"):
        DQNConfig(**{field: value})
    DQNConfig(warmup="hardcoded", **{field: value})


@pytest.mark.parametrize(
    "update, after, expected",
    [
        (0, False, 1.0),  # burn-in: 4 updates of 10
        (3, False, 1.0),
        (4, False, 0.0),  # cut off after it
        (3, True, 1.0),
        (4, True, 1.0),  # decaying: 1 − (u − 4) / 6
        (7, True, 0.5),
        (9, True, 1.0 / 6.0),
        (10, True, 0.0),
        (12, True, 0.0),
    ],
)
def test_margin_weight_is_one_in_the_burn_in_then_cut_off_or_decayed(update, after, expected):
    weight = margin_weight(update, burn_in=4, total=10, after_burn_in=after)
    assert weight == pytest.approx(expected)


def test_the_margin_loss_goes_on_after_the_burn_in_weighted_by_its_decay():
    config = DQNConfig(
        hidden_sizes=(16,), warmup="hardcoded", burn_in_updates=2, margin_after_burn_in=True
    )
    learner = DQNLearner(2, 2, config=config, seed=0, total_updates=6)
    rng = np.random.default_rng(0)
    seen = ["losses/margin" in learner.update(_demo_batch(8, rng)) for _ in range(7)]
    # updates 0-1: burn-in; 2-5: weights 1, 3/4, 1/2, 1/4; from the run's end (6): none
    assert seen == [True] * 6 + [False]
    with pytest.raises(ValueError, match="pass total_updates"):
        DQNLearner(2, 2, config=config, seed=0)


def test_the_dqn_learner_publishes_and_checkpoints_the_tree_only_flag():
    learner = DQNLearner(2, 2, config=DQNConfig(hidden_sizes=(4,), warmup="hardcoded"), seed=0)
    assert TREE_ONLY not in learner.policy_state()
    assert learner.tree_state()[TREE_ONLY].item() == 1.0
    learner.keep_tree()
    again = DQNLearner(2, 2, config=DQNConfig(hidden_sizes=(4,), warmup="hardcoded"), seed=1)
    again.load_state_dict(learner.state_dict())
    assert again.policy_state()[TREE_ONLY].item() == 1.0


@pytest.mark.parametrize(
    "terminated, discounts",
    [
        ([0.0, 0.0, 0.0], [0.125, 0.25, 0.5]),  # γ^(n − j): each step bootstraps past the end
        ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),  # the window ends in a terminal state
    ],
)
def test_window_returns_to_the_windows_end_from_every_step(terminated, discounts):
    from learner.dqn.learning import window_returns

    rewards = torch.tensor([[1.0, 2.0, 3.0]])
    returns, discount = window_returns(rewards, torch.tensor([terminated]).bool(), 0.5)
    # R_0 = 1 + 0.5·2 + 0.25·3, R_1 = 2 + 0.5·3, R_2 = 3.
    torch.testing.assert_close(returns, torch.tensor([[2.75, 3.5, 3.0]]))
    torch.testing.assert_close(discount, torch.tensor([discounts]))


@pytest.mark.parametrize(
    "terminated, discounts",
    [
        ([0.0, 0.0, 0.0], [0.25, 0.5]),  # a time-limit cut: γ^(m − j) from the last real step
        ([0.0, 1.0, 1.0], [0.0, 0.0]),  # the episode ended in a terminal state
    ],
)
def test_window_returns_stop_at_the_episodes_end_in_a_padded_window(terminated, discounts):
    from learner.dqn.learning import window_returns

    # Two steps of the episode, then its last step repeated (reward and all).
    rewards = torch.tensor([[1.0, 2.0, 2.0]])
    valid = torch.tensor([[True, True, False]])
    returns, discount = window_returns(rewards, torch.tensor([terminated]).bool(), 0.5, valid)
    # R_0 = 1 + 0.5·2, R_1 = 2; the padding's own values are never used.
    torch.testing.assert_close(returns[:, :2], torch.tensor([[2.0, 2.0]]))
    torch.testing.assert_close(discount[:, :2], torch.tensor([discounts]))


def test_a_padded_window_trains_as_the_episodes_steps_alone():
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner

    config = DQNConfig(hidden_sizes=(8,), target_update_every=2)
    short, padded = (DQNLearner(2, 2, config=config, seed=0) for _ in range(2))
    rng = torch.Generator().manual_seed(0)
    for _ in range(3):
        window = {  # 4 windows of the 2 steps that end their episodes (some terminal)
            "obs": torch.randn(4, 2, 2, generator=rng),
            "action": torch.randint(0, 2, (4, 2), generator=rng),
            "reward": torch.randn(4, 2, generator=rng),
            "terminated": torch.cat(
                [torch.zeros(4, 1, dtype=torch.bool), torch.rand(4, 1, generator=rng) < 0.5], 1
            ),
            "next_obs": torch.randn(4, 2, 2, generator=rng),
        }
        # The same windows as replay serves them to a learner of 3-step windows.
        filled = {k: torch.cat([v, v[:, -1:]], 1) for k, v in window.items()}
        filled["_valid"] = torch.tensor([[True, True, False]]).repeat(4, 1)
        a = short.update(window)
        b = padded.update(filled)
        assert a["losses/q"] == pytest.approx(b["losses/q"], rel=1e-6)
    for p, q in zip(short.q.parameters(), padded.q.parameters(), strict=True):
        torch.testing.assert_close(p, q)


def test_windows_of_one_step_train_exactly_as_single_transitions():
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner

    config = DQNConfig(hidden_sizes=(8,), target_update_every=2)
    flat, windowed = (DQNLearner(2, 2, config=config, seed=0) for _ in range(2))
    rng = torch.Generator().manual_seed(0)
    for _ in range(3):
        batch = {
            "obs": torch.randn(8, 2, generator=rng),
            "action": torch.randint(0, 2, (8,), generator=rng),
            "reward": torch.randn(8, generator=rng),
            "terminated": torch.rand(8, generator=rng) < 0.3,
            "next_obs": torch.randn(8, 2, generator=rng),
        }
        a = flat.update(batch)
        b = windowed.update({k: v.unsqueeze(1) for k, v in batch.items()})
        assert a["losses/q"] == pytest.approx(b["losses/q"], rel=1e-6)
    for p, q in zip(flat.q.parameters(), windowed.q.parameters(), strict=True):
        torch.testing.assert_close(p, q)


def test_n_step_dqn_samples_windows_of_n_steps():
    from gymnasium import spaces

    from learner.agent import Budget
    from learner.dqn.builder import DQNBuilder
    from learner.dqn.config import DQNConfig

    budget = Budget(
        env_steps=5000, learning_starts=1000, updates_per_env_step=0.5, slack_env_steps=0
    )
    for n in (1, 3):
        builder = DQNBuilder(
            spaces.Box(-1.0, 1.0, shape=(4,)),
            spaces.Discrete(2),
            config=DQNConfig(hidden_sizes=(4,), n_step=n),
            budget=budget,
            seed=0,
        )
        assert [p.sequence_length for p in builder.phases()] == [n]
    with pytest.raises(ValueError, match="n_step"):
        DQNConfig(n_step=0)
