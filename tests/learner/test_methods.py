"""The paper's targets and losses, each against values computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from actors.behaviours.backbone import BackboneBehaviour, compose_action
from actors.behaviours.epsilon_greedy import epsilon_greedy, linear_epsilon
from actors.behaviours.options import HARDCODED, RL, OptionsBehaviour
from learner.backbone.learning import teacher_target
from learner.backbone.networks import zero_output_
from learner.dqn.learning import double_q_target, linear_decay
from learner.options.targets import (
    gaussian_log_prob,
    importance_ratio,
    k_step_return,
    retrace_targets,
    retrace_traces,
)
from learner.pretrain.learning import imitation_loss, td3_bc_actor_loss
from learner.td3.networks import Actor


class Table(nn.Module):
    """A "network" that returns fixed rows (one row: the same for every input)."""

    def __init__(self, rows: list[list[float]]) -> None:
        super().__init__()
        self.rows = torch.tensor(rows)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        if len(self.rows) == 1:
            return self.rows[0].expand(*obs.shape[:-1], -1)
        return self.rows


# --- Double DQN and eq. (13) ------------------------------------------------------------


def test_double_dqn_target_lets_the_online_net_choose_and_the_target_net_value():
    online = Table([[1.0, 3.0], [5.0, 2.0]])  # argmax: action 1, then action 0
    target = Table([[10.0, 20.0], [30.0, 40.0]])
    reward = torch.tensor([1.0, 2.0])
    discount = 0.9 * (1.0 - torch.tensor([0.0, 1.0]))  # second s' is terminal
    y = double_q_target(reward, discount, torch.zeros(2, 4), online=online, target=target)
    # 1 + 0.9 * Q_target(s', 1) = 1 + 18; terminal: just r. (Plain DQN would take 40 for row 2.)
    torch.testing.assert_close(y, torch.tensor([19.0, 2.0]))


@pytest.mark.parametrize(
    "terminated, expected",
    [
        # Σ γ^i r_i = 1 + 0.5·2 + 0.25·4 = 3; γ^3 = 0.125; Q_target(s_3, argmax online = 0) = 8.
        (False, 3.0 + 0.125 * 8.0),
        (True, 3.0),  # the window ends on a terminal state: no bootstrap
    ],
)
def test_eq13_k_step_option_target(terminated, expected):
    rewards = torch.tensor([[1.0, 2.0, 4.0]])
    done = torch.tensor([[False, False, terminated]])
    returns, discount = k_step_return(rewards, done, gamma=0.5)
    y = double_q_target(
        returns,
        discount,
        torch.zeros(1, 3),
        online=Table([[2.0, 1.0]]),
        target=Table([[8.0, 99.0]]),
    )
    torch.testing.assert_close(y, torch.tensor([expected]))


# --- Retrace, eq. (14) ------------------------------------------------------------------


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


# --- Backbone, eqs. (10) and (11) -------------------------------------------------------


def test_backbone_action_composition_clips_the_correction_then_the_action():
    mu = np.array([[1.8], [-1.0], [0.0]], np.float32)
    correction = np.array([[1.0], [-0.3], [-5.0]], np.float32)
    action = compose_action(mu, correction, limit=0.5, low=np.array([-2.0]), high=np.array([2.0]))
    # 1.8 + 0.5 = 2.3 -> 2.0;  -1.0 - 0.3 = -1.3;  0.0 + clip(-5) = -0.5
    np.testing.assert_allclose(action, [[2.0], [-1.3], [-0.5]], rtol=1e-6)


def _pendulum_backbone(correction: nn.Module, backbone, **kwargs) -> BackboneBehaviour:
    """A backbone behaviour over Pendulum's torque box [−2, 2], exploration σ = 0.2."""
    box = {"low": np.array([-2.0]), "high": np.array([2.0])}
    return BackboneBehaviour(correction, backbone, std=0.2, prefill_std=0.3, **box, **kwargs)


def test_correction_network_starts_at_zero_so_the_agent_starts_as_the_backbone():
    correction = zero_output_(Actor(3, 1, np.array([-0.5]), np.array([0.5]), (8,)))
    backbone = lambda obs: np.full((len(obs), 1), 1.7, np.float32)  # noqa: E731
    behaviour = _pendulum_backbone(correction, backbone, limit=0.5)
    obs = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    np.testing.assert_allclose(behaviour.greedy(obs), np.full((5, 1), 1.7))
    env_action, columns = behaviour.act(obs, np.random.default_rng(1), warmup=False)
    # Replay stores μ(s) and the (unclipped) correction separately; noise is on the correction.
    np.testing.assert_allclose(columns["backbone_action"], np.full((5, 1), 1.7))
    expected = np.clip(1.7 + np.clip(columns["action"], -0.5, 0.5), -2.0, 2.0)
    np.testing.assert_allclose(env_action, expected, rtol=1e-6)
    assert np.abs(columns["action"]).max() > 0.0


class _Recorder(nn.Module):
    """A correction network that records its input and outputs zero."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.seen = x.clone()
        return torch.zeros(x.shape[0], 1)


def test_observed_backbone_is_an_input_of_the_correction_and_recorded_at_s_prime():
    correction = _Recorder()
    backbone = lambda obs: np.where(obs[:, 2:] >= 0, 2.0, -2.0).astype(np.float32)  # noqa: E731
    behaviour = _pendulum_backbone(correction, backbone, limit=4.0, observe_backbone=True)
    obs = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -3.0]], np.float32)
    behaviour.greedy(obs)
    # [s, μ(s) / 2]: μ = +2 and −2 -> +1 and −1.
    torch.testing.assert_close(
        correction.seen, torch.tensor([[1.0, 0.0, 0.5, 1.0], [0.0, 1.0, -3.0, -1.0]])
    )
    assert "next_backbone_action" in behaviour.columns()
    next_obs = np.array([[1.0, 0.0, -0.1], [0.0, 1.0, 0.2]], np.float32)
    np.testing.assert_allclose(
        behaviour.next_columns(next_obs)["next_backbone_action"], [[-2.0], [2.0]]
    )


def test_observed_backbone_ticks_mu_once_per_state():
    ticked: list[int] = []

    def backbone(obs: np.ndarray) -> np.ndarray:
        ticked.append(len(obs))
        return np.where(obs[:, 2:] >= 0, 2.0, -2.0).astype(np.float32)

    behaviour = _pendulum_backbone(_Recorder(), backbone, limit=4.0, observe_backbone=True)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 3)).astype(np.float32)
    behaviour.act(obs, rng, warmup=False)
    next_obs = rng.normal(size=(4, 3)).astype(np.float32)
    mu_next = behaviour.next_columns(next_obs)["next_backbone_action"]
    restarted = next_obs.copy()
    restarted[1] = [0.0, 1.0, -5.0]  # env 1's episode ended: its next s is a reset state
    _, columns = behaviour.act(restarted, rng, warmup=False)
    # 4 rows, 4 rows of s', then only the restarted row: μ(s') is reused for the others.
    assert ticked == [4, 4, 1]
    np.testing.assert_array_equal(columns["backbone_action"][[0, 2, 3]], mu_next[[0, 2, 3]])
    np.testing.assert_array_equal(columns["backbone_action"][1], [-2.0])


def test_observing_learner_appends_mu_to_obs_and_next_obs():
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    learner = ObservingBackboneLearner(
        3, np.array([4.0], np.float32), np.array([2.0]), config=TD3Config(hidden_sizes=(8,)), seed=0
    )
    assert learner.actor.net[0].in_features == 4  # s (3) + μ(s) (1)
    batch = {
        "obs": torch.zeros(5, 3),
        "action": torch.zeros(5, 1),
        "backbone_action": torch.full((5, 1), 2.0),
        "reward": torch.ones(5),
        "terminated": torch.zeros(5, dtype=torch.bool),
        "next_obs": torch.zeros(5, 3),
    }
    with pytest.raises(ValueError, match="next_backbone_action"):
        learner.update(batch)
    metrics = learner.update({**batch, "next_backbone_action": torch.full((5, 1), -2.0)})
    assert math.isfinite(metrics["losses/critic"])


def test_observe_backbone_refuses_a_teacher():
    from learner.backbone.config import BackboneConfig

    with pytest.raises(ValueError, match="observe_backbone"):
        BackboneConfig(observe_backbone=True, teacher="runs/teacher")


def test_eq11_teacher_target():
    y = teacher_target(
        torch.tensor([1.0, -1.0]),
        torch.tensor([False, True]),
        gamma=0.9,
        teacher_next_value=torch.tensor([-10.0, -20.0]),
        next_correction_value=torch.tensor([2.0, 3.0]),
    )
    # 1 + 0.9·(−10 + 2) = −6.2; the terminal row keeps only r.
    torch.testing.assert_close(y, torch.tensor([-6.2, -1.0]))


# --- Pre-training: eq. (8), TD3+BC ------------------------------------------------------


def test_imitation_loss_eq8_and_td3_bc_actor_loss():
    pi = torch.tensor([[1.0, 0.0], [0.0, 0.0]])
    mu = torch.tensor([[0.0, 0.0], [0.0, 2.0]])
    # per state Σ_j: 1 and 4; mean 2.5
    torch.testing.assert_close(imitation_loss(pi, mu), torch.tensor(2.5))
    q = torch.tensor([-4.0, -2.0])  # mean|Q| = 3 -> λ = 2.5 / 3
    expected = -(2.5 / 3) * (-3.0) + 5.0 / 4  # −λ mean Q + mean over all elements of (π − μ)²
    torch.testing.assert_close(td3_bc_actor_loss(q, pi, mu, alpha=2.5), torch.tensor(expected))


# --- ε-greedy and the options behaviour -------------------------------------------------


def test_epsilon_greedy_log_likelihoods_and_schedule():
    q = np.array([[0.0, 1.0, 0.0]] * 4000)
    action, log_prob = epsilon_greedy(q, 0.3, np.random.default_rng(0))
    greedy = action == 1
    np.testing.assert_allclose(log_prob[greedy], math.log(0.7 + 0.1), rtol=1e-6)
    np.testing.assert_allclose(log_prob[~greedy], math.log(0.1), rtol=1e-6)
    assert abs(greedy.mean() - 0.8) < 0.03
    assert linear_epsilon(500, start=1.0, end=0.1, decay_steps=1000) == pytest.approx(0.55)
    assert linear_epsilon(5000, start=1.0, end=0.1, decay_steps=1000) == pytest.approx(0.1)


def greedy_options(option_q: nn.Module, actor: nn.Module) -> OptionsBehaviour:
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
    behaviour = greedy_options(Table([[0.0, 1.0]]), Table([[0.25]]))  # Q_Ω prefers RL
    rng, obs = np.random.default_rng(0), np.zeros((1, 3), np.float32)
    steps = []
    for t in range(5):
        _, columns = behaviour.act(obs, rng, warmup=False)
        steps.append((int(columns["option"][0]), int(columns["option_step"][0])))
        if t == 3:
            behaviour.end_episodes(np.array([True]))
    assert steps == [(RL, 0), (RL, 1), (RL, 2), (RL, 0), (RL, 0)]
    # The hard-coded option acts μ(s) and records no density.
    behaviour.option_q = Table([[1.0, 0.0]])
    behaviour.end_episodes(np.array([True]))
    action, columns = behaviour.act(obs, rng, warmup=False)
    assert columns["option"][0] == HARDCODED and columns["log_prob"][0] == 0.0
    np.testing.assert_allclose(action, [[-1.0]])


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


def test_options_greedy_policy_rechooses_options_with_newly_loaded_weights():
    def options_table(q: list[float]) -> dict[str, torch.Tensor]:
        return {"options.rows": torch.tensor([q]), "actor.rows": torch.tensor([[0.25]])}

    class Loadable(Table):
        def load_state_dict(self, state, strict=True):  # noqa: ANN001
            self.rows = state["rows"]

    behaviour = greedy_options(Loadable([[0.0, 1.0]]), Loadable([[0.25]]))
    obs = np.zeros((2, 3), np.float32)
    behaviour.load(options_table([0.0, 1.0]))  # prefers RL
    np.testing.assert_allclose(behaviour.greedy(obs), [[0.25], [0.25]])
    behaviour.load(options_table([1.0, 0.0]))  # now prefers the hard-coded option
    np.testing.assert_allclose(behaviour.greedy(obs), [[-1.0], [-1.0]])
    assert behaviour.stats() == {"options/rl_fraction": 0.5}


def test_backbone_critic_burn_in_is_extra_updates_at_learning_starts_with_the_actor_frozen():
    from service.run.config import load_preset
    from service.run.registry import make_builder

    config = load_preset(
        "pendulum-backbone",
        env_steps=3000,
        learning_starts=2000,
        **{"td3.burn_in_updates": 500, "td3.frozen_actor_updates": 500},
    )
    builder = make_builder(config)
    (phase,) = builder.phases()
    # 1,000 online updates (3,000 - 2,000 steps at 1 per step) plus the 500 of the burn-in,
    # which the rate limiter lets the learner draw at min_size: 500 batches of 256 items.
    assert phase.updates == 1500
    assert phase.min_size == 2000
    assert phase.sample_credit == 500 * 256
    learner = builder.make_learner()
    before = [p.clone() for p in learner.actor.parameters()]
    batch = {
        "obs": torch.zeros(256, 3),
        "action": torch.zeros(256, 1),
        "backbone_action": torch.full((256, 1), 2.0),
        "next_backbone_action": torch.full((256, 1), -2.0),
        "reward": torch.ones(256),
        "terminated": torch.zeros(256, dtype=torch.bool),
        "next_obs": torch.zeros(256, 3),
    }
    for _ in range(500):
        learner.update(batch)
    assert learner.num_actor_updates == 0  # the correction is still exactly zero
    assert all(torch.equal(a, b) for a, b in zip(before, learner.actor.parameters(), strict=True))
    learner.update(batch)
    learner.update(batch)
    assert learner.num_actor_updates == 1
