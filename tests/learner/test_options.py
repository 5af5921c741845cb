"""Hierarchical options (learner/options and the options behaviour): the k-step option target
(eq. 13), Retrace (eq. 14) and option scheduling, against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from actors.behaviours.options import HARDCODED, RL, OptionsBehaviour
from learner.dqn.learning import double_q_target
from learner.options.targets import (
    gaussian_log_prob,
    importance_ratio,
    k_step_return,
    retrace_targets,
    retrace_traces,
)
from service.core import as_arrays
from tests.learner.helpers import FixedRows, Table

# --- the k-step option target, eq. (13) -----------------------------------------------


@pytest.mark.parametrize(
    "rewards, done, valid, expected",
    [
        # Σ γ^i r_i = 1 + 0.5·2 + 0.25·4 = 3; γ^3 = 0.125; Q_target(s_3, argmax online = 0) = 8.
        ([1.0, 2.0, 4.0], [False, False, False], None, 3.0 + 0.125 * 8.0),
        ([1.0, 2.0, 4.0], [False, False, True], None, 3.0),  # a terminal state: no bootstrap
        # An option cut short by its episode's end after 2 steps, the last one repeated after
        # it: 1 + 0.5·2 = 2, then γ^2 = 0.25 past a time limit, nothing past a terminal state.
        ([1.0, 2.0, 2.0], [False, False, False], [True, True, False], 2.0 + 0.25 * 8.0),
        ([1.0, 2.0, 2.0], [False, True, True], [True, True, False], 2.0),
    ],
)
def test_eq13_k_step_option_target(rewards, done, valid, expected):
    returns, discount = k_step_return(
        torch.tensor([rewards]),
        torch.tensor([done]),
        gamma=0.5,
        valid=None if valid is None else torch.tensor([valid]),
    )
    y = double_q_target(
        returns,
        discount,
        torch.zeros(1, 3),
        online=Table([[2.0, 1.0]]),
        target=Table([[8.0, 99.0]]),
    )
    torch.testing.assert_close(y, torch.tensor([expected]))


# --- Retrace, eq. (14) ----------------------------------------------------------------


def test_gaussian_log_likelihood_ratio():
    # a = 0.5, σ = 0.5: under π (mean 0.5) z = 0, under π_old (mean 0) z = 1.
    action, std = torch.tensor([[0.5]]), 0.5
    behaviour_log_prob = torch.tensor([-0.5 - math.log(0.5) - 0.5 * math.log(2 * math.pi)])
    torch.testing.assert_close(
        gaussian_log_prob(action, torch.zeros(1, 1), std), behaviour_log_prob
    )
    ratio = importance_ratio(action, torch.tensor([[0.5]]), std, behaviour_log_prob)
    torch.testing.assert_close(ratio, torch.tensor([math.exp(0.5)]))


@pytest.mark.parametrize(
    "last_terminated, expected",
    [
        # Q2 = 3 + 0.9·30 = 30;  Q1 = 2 + 0.9·(20 + 0.5·(30 − 18)) = 25.4;
        # Q0 = 1 + 0.9·(10 + 1·(25.4 − 11)) = 22.96
        (False, [22.96, 25.4, 30.0]),
        # Q2 = 3 (terminal);  Q1 = 2 + 0.9·(20 + 0.5·(3 − 18)) = 13.25;
        # Q0 = 1 + 0.9·(10 + 1·(13.25 − 11)) = 12.025
        (True, [12.025, 13.25, 3.0]),
    ],
)
def test_retrace_on_a_three_step_window(last_terminated, expected):
    rewards = torch.tensor([[1.0, 2.0, 3.0]])
    discounts = 0.9 * (1.0 - torch.tensor([[0.0, 0.0, float(last_terminated)]]))
    next_values = torch.tensor([[10.0, 20.0, 30.0]])  # V(s1), V(s2), V(s3)
    next_q = torch.tensor([[11.0, 18.0, 0.0]])  # Q(s1, a1), Q(s2, a2), unused
    # ρ1 = 2 is truncated to c1 = 1; ρ2 = 0.5 passes as c2 = 0.5 (λ = 1).
    traces = retrace_traces(torch.tensor([[9.0, 2.0, 0.5]]), lam=1.0)
    torch.testing.assert_close(traces, torch.tensor([[1.0, 1.0, 0.5]]))
    next_traces = torch.cat([traces[:, 1:], torch.zeros(1, 1)], dim=1)
    q_ret = retrace_targets(rewards, discounts, next_values, next_q, next_traces)
    torch.testing.assert_close(q_ret, torch.tensor([expected]))


def test_retrace_with_zero_traces_is_the_one_step_target():
    rewards, discounts = torch.tensor([[1.0, 2.0]]), torch.tensor([[0.9, 0.9]])
    next_values = torch.tensor([[10.0, 20.0]])
    q_ret = retrace_targets(
        rewards, discounts, next_values, torch.tensor([[50.0, 0.0]]), torch.zeros(1, 2)
    )
    torch.testing.assert_close(q_ret, rewards + discounts * next_values)


class ConstantCritic(nn.Module):
    """(Q1, Q2)(s, a) = (value, value + 1): the TD3 target takes the smaller."""

    def __init__(self, value: float) -> None:
        super().__init__()
        self.value = value

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        q = torch.full(obs.shape[:-1], self.value)
        return q, q + 1.0


def test_options_retrace_uses_option_values_and_cuts_traces_at_option_boundaries():
    from learner.dqn.config import DQNConfig
    from learner.dqn.learning import DQNLearner
    from learner.options.learning import OptionsLearner, RetraceTD3Learner
    from learner.td3.config import TD3Config

    rl = RetraceTD3Learner(
        3, 1, np.array([-2.0]), np.array([2.0]), config=TD3Config(hidden_sizes=(4,)), seed=0
    )
    learner = OptionsLearner(
        DQNLearner(3, 2, config=DQNConfig(hidden_sizes=(4,)), seed=0),
        rl,
        option_length=3,
        retrace_lambda=1.0,
        behaviour_std=0.5,
        gamma=0.9,
    )
    learner.options.target_q = Table([[30.0, 20.0]])  # Q_Ω(s, hard-coded), Q_Ω(s, RL)
    rl.target_critic = ConstantCritic(5.0)
    rl.actor.forward = lambda obs: torch.full((*obs.shape[:-1], 1), 0.5)  # π(s) = 0.5
    log_pi = -math.log(0.5) - 0.5 * math.log(2 * math.pi)  # log N(0.5 | 0.5, 0.5²)
    window = {
        "obs": torch.zeros(1, 3, 3),
        "next_obs": torch.zeros(1, 3, 3),
        "action": torch.tensor([[[0.0], [0.5], [0.5]]]),
        "reward": torch.tensor([[1.0, 2.0, 3.0]]),
        "terminated": torch.zeros(1, 3, dtype=torch.bool),
        "option": torch.full((1, 3), RL),
        # Steps 1-2 of one RL option (it ends after the second), then a new RL option.
        "option_step": torch.tensor([[1, 2, 0]]),
        # ρ_1 = 2 (truncated to c_1 = 1); step 2 starts a new option: its trace is cut.
        "log_prob": torch.tensor([[0.0, log_pi - math.log(2.0), log_pi]]),
    }
    q_ret = learner.retrace(window)
    # Q2 = 3 + 0.9·Q_Ω(s3, RL) = 21;  Q1 = 2 + 0.9·max_o Q_Ω(s2, o) = 29 (option ended, c2 = 0);
    # Q0 = 1 + 0.9·(Q_Ω(s1, RL) + c1·(Q1 − Q'(s1, a1))) = 1 + 0.9·(20 + 29 − 5) = 40.6
    torch.testing.assert_close(q_ret, torch.tensor([[40.6, 29.0, 21.0]]))

    # The episode ended (a time limit) after step 1: replay repeats step 1 to fill the
    # window. Its trace would be c = 1 (the copy sits inside the option); the episode's last
    # step takes none: Q1 = 2 + 0.9·V(s2) = 2 + 0.9·Q_Ω(s2, RL) = 20 (the option goes on).
    window["option_step"] = torch.tensor([[0, 1, 1]])
    window["reward"] = torch.tensor([[1.0, 2.0, 2.0]])
    window["log_prob"] = torch.tensor([[0.0, log_pi, log_pi]])
    window["_valid"] = torch.tensor([[True, True, False]])
    # Q0 = 1 + 0.9·(20 + c1·(Q1 − 5)) = 1 + 0.9·(20 + 15) = 32.5
    torch.testing.assert_close(learner.retrace(window)[:, :2], torch.tensor([[32.5, 20.0]]))


# --- the options behaviour ------------------------------------------------------------


def greedy_options(option_q: FixedRows, actor: FixedRows) -> OptionsBehaviour:
    """k = 3, ε = 0, μ(s) = −1 everywhere."""
    return OptionsBehaviour(
        option_q,
        actor,
        lambda obs: np.full((len(obs), 1), -1.0, np.float32),
        option_length=3,
        std=0.1,
        low=np.array([-2.0]),
        high=np.array([2.0]),
        epsilon_start=0.0,
        epsilon_end=0.0,
        decay_env_steps=1,
        num_actors=1,
    )


def test_options_behaviour_holds_an_option_for_k_steps_and_restarts_on_episode_end():
    behaviour = greedy_options(FixedRows([[0.0, 1.0]]), FixedRows([[0.25]]))  # Q_Ω prefers RL
    rng, obs = np.random.default_rng(0), np.zeros((1, 3), np.float32)
    steps = []
    for t in range(5):
        _, columns = behaviour.act(obs, rng, warmup=False)
        steps.append((int(columns["option"][0]), int(columns["option_step"][0])))
        if t == 3:
            behaviour.end_episodes(np.array([True]))
    assert steps == [(RL, 0), (RL, 1), (RL, 2), (RL, 0), (RL, 0)]
    # The hard-coded option acts μ(s) and records no density.
    behaviour.option_q = FixedRows([[1.0, 0.0]])
    behaviour.end_episodes(np.array([True]))
    action, columns = behaviour.act(obs, rng, warmup=False)
    assert columns["option"][0] == HARDCODED and columns["log_prob"][0] == 0.0
    np.testing.assert_allclose(action, [[-1.0]])


def test_options_behaviour_keeps_each_environments_clock_when_they_act_apart():
    """Real-time clients step at their own pace: the actor acts for varying subsets of
    its environments (`envs`), and each one's option clock is its own."""
    behaviour = greedy_options(FixedRows([[0.0, 1.0]]), FixedRows([[0.25]]))
    rng, one = np.random.default_rng(0), np.zeros((1, 3), np.float32)
    clock = {0: [], 1: []}
    for env in (0, 0, 1, 0, 1, 1, 1):
        _, columns = behaviour.act(one, rng, warmup=False, envs=np.array([env]))
        clock[env].append(int(columns["option_step"][0]))
    assert clock == {0: [0, 1, 2], 1: [0, 1, 2, 0]}
    behaviour.end_episodes(np.array([True]), envs=np.array([0]))  # env 0's episode ended
    _, columns = behaviour.act(np.zeros((2, 3), np.float32), rng, warmup=False,
                               envs=np.array([1, 0]))  # fmt: skip
    assert columns["option_step"].tolist() == [1, 0]


def test_options_greedy_policy_rechooses_options_with_newly_loaded_weights():
    def options_table(q: list[float]) -> dict[str, np.ndarray]:
        return {"options.rows": np.array([q], np.float32), "actor.rows": np.array([[0.25]])}

    behaviour = greedy_options(FixedRows([[0.0, 1.0]]), FixedRows([[0.25]]))
    obs = np.zeros((2, 3), np.float32)
    behaviour.load(options_table([0.0, 1.0]))  # prefers RL
    np.testing.assert_allclose(behaviour.greedy(obs), [[0.25], [0.25]])
    behaviour.load(options_table([1.0, 0.0]))  # now prefers the hard-coded option
    np.testing.assert_allclose(behaviour.greedy(obs), [[-1.0], [-1.0]])
    assert behaviour.stats() == {"options/rl_fraction": 0.5}


# --- past the paper: a residual RL option and a switching margin ------------------------


def residual_options(option_q: FixedRows, actor: FixedRows, margin: float) -> OptionsBehaviour:
    """As `greedy_options` (μ(s) = −1, box [−2, 2]), with a residual RL option, L = 4."""
    return OptionsBehaviour(
        option_q,
        actor,
        lambda obs: np.full((len(obs), 1), -1.0, np.float32),
        option_length=3,
        std=0.1,
        low=np.array([-2.0]),
        high=np.array([2.0]),
        epsilon_start=0.0,
        epsilon_end=0.0,
        decay_env_steps=1,
        num_actors=1,
        residual_limit=4.0,
        switch_margin=margin,
    )


def test_residual_rl_option_acts_the_tree_plus_a_correction_that_sees_the_tree():
    actor = FixedRows([[0.5]])
    behaviour = residual_options(FixedRows([[0.0, 1.0]]), actor, margin=0.0)
    obs = np.zeros((1, 3), np.float32)
    # Greedy: μ(s) + π([s, μ(s) / 2]) = −1 + 0.5.
    np.testing.assert_allclose(behaviour.greedy(obs), [[-0.5]])
    np.testing.assert_array_equal(actor.seen, [[0.0, 0.0, 0.0, -0.5]])
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=False)
    correction = columns["action"] - columns["hardcoded_action"]
    np.testing.assert_allclose(columns["hardcoded_action"], [[-1.0]])
    np.testing.assert_allclose(action, -1.0 + correction, rtol=1e-6)
    # The recorded density is the correction's, N(0.5, 0.1²).
    z = (correction[0, 0] - 0.5) / 0.1
    expected = -0.5 * z**2 - math.log(0.1) - 0.5 * math.log(2 * math.pi)
    assert columns["log_prob"][0] == pytest.approx(expected, rel=1e-5)
    # Warm-up corrections are uniform over [−L, L] = [−4, 4].
    behaviour.end_episodes(np.array([True]))
    _, columns = behaviour.act(obs, np.random.default_rng(0), warmup=True)
    assert columns["log_prob"][0] == pytest.approx(-math.log(8.0))


@pytest.mark.parametrize("margin, option", [(0.0, RL), (0.4, RL), (0.6, HARDCODED)])
def test_switching_margin_keeps_the_tree_unless_the_rl_option_is_clearly_better(margin, option):
    behaviour = residual_options(FixedRows([[0.0, 0.5]]), FixedRows([[0.5]]), margin=margin)
    _, columns = behaviour.act(np.zeros((1, 3), np.float32), np.random.default_rng(0), warmup=False)
    assert columns["option"][0] == option


def test_residual_options_learner_starts_as_the_tree_and_learns_the_correction():
    from gymnasium import spaces

    from learner.agent import Budget
    from learner.dqn.config import DQNConfig
    from learner.options.builder import OptionsBuilder
    from learner.options.config import OptionsConfig
    from learner.td3.builder import TD3Builder
    from learner.td3.config import TD3Config

    budget = Budget(
        env_steps=2000, learning_starts=100, updates_per_env_step=1.0, slack_env_steps=0
    )
    td3 = TD3Builder(
        spaces.Box(-8.0, 8.0, shape=(3,)),
        spaces.Box(-2.0, 2.0, shape=(1,)),
        config=TD3Config(hidden_sizes=(8,), batch_size=4),
        method="options",
        budget=budget,
        seed=0,
    )
    builder = OptionsBuilder(
        "actors.trees.pendulum:swing_up",
        td3,
        dqn=DQNConfig(hidden_sizes=(8,)),
        config=OptionsConfig(option_length=3, residual_limit=4.0),
    )
    learner = builder.make_learner()
    x = torch.randn(5, 4)  # [s, μ(s) / 2]
    torch.testing.assert_close(learner.rl.actor(x), torch.zeros(5, 1))
    window = {
        "obs": torch.ones(1, 3, 3),
        "action": torch.tensor([[[1.5], [0.5], [-2.0]]]),
        "hardcoded_action": torch.tensor([[[2.0], [-2.0], [-2.0]]]),
    }
    view = learner.residual_view(window)
    torch.testing.assert_close(view["action"], torch.tensor([[[-0.5], [2.5], [0.0]]]))
    torch.testing.assert_close(view["rl_obs"][0, :, 3], torch.tensor([1.0, -1.0, -1.0]))
    # The behaviour's RL actor has the learner's shape: it loads the broadcast weights.
    behaviour = builder.make_behaviour(num_actors=1)
    behaviour.load(as_arrays(learner.policy_state()))


def test_intra_option_learning_trains_the_rl_option_on_every_step_of_a_window():
    from gymnasium import spaces

    from learner.agent import Budget
    from learner.dqn.config import DQNConfig
    from learner.options.builder import OptionsBuilder
    from learner.options.config import OptionsConfig
    from learner.td3.builder import TD3Builder
    from learner.td3.config import TD3Config

    budget = Budget(
        env_steps=2000, learning_starts=100, updates_per_env_step=1.0, slack_env_steps=0
    )
    td3 = TD3Builder(
        spaces.Box(-8.0, 8.0, shape=(3,)),
        spaces.Box(-2.0, 2.0, shape=(1,)),
        config=TD3Config(hidden_sizes=(8,), batch_size=4),
        method="options",
        budget=budget,
        seed=0,
    )
    config = OptionsConfig(option_length=3, residual_limit=4.0, intra_option=True)
    learner = OptionsBuilder(
        "actors.trees.pendulum:swing_up", td3, dqn=DQNConfig(hidden_sizes=(8,)), config=config
    ).make_learner()
    seen = []
    learner.rl.update = lambda batch: seen.append(batch) or {}  # type: ignore[method-assign]
    g = torch.Generator().manual_seed(0)
    windows = {
        "obs": torch.randn(2, 3, 3, generator=g),
        "next_obs": torch.randn(2, 3, 3, generator=g),
        "action": torch.randn(2, 3, 1, generator=g),
        "hardcoded_action": torch.randn(2, 3, 1, generator=g),
        "reward": torch.randn(2, 3, generator=g),
        "terminated": torch.zeros(2, 3, dtype=torch.bool),
        "option": torch.tensor([[HARDCODED] * 3, [RL] * 3]),  # tree steps train it too
        "option_step": torch.tensor([[0, 1, 2], [0, 1, 2]]),
        "log_prob": torch.zeros(2, 3),
    }
    learner.update(windows)
    (batch,) = seen
    assert batch["obs"].shape == (4, 4)  # k − 1 = 2 steps of each of 2 windows, [s, μ(s)/2]
    # s_{t+1} is the next row of the window, μ(s_{t+1}) included.
    torch.testing.assert_close(batch["next_obs"][0], batch["obs"][1])
    torch.testing.assert_close(batch["obs"][0, :3], windows["obs"][0, 0])
    expected = windows["action"][0, 0] - windows["hardcoded_action"][0, 0]
    torch.testing.assert_close(batch["action"][0], expected)
