"""Tests of the hard-coded Pendulum tree, the behaviour-policy samplers and evaluation."""

import math
import pickle

import gymnasium as gym
import numpy as np
import pytest
from py_trees.common import Status

from actors.evaluator import random_policy_for, run_episodes
from actors.hardcoded import ImportedPolicy, TreePolicy, make_hardcoded_policy
from actors.policies import GaussianExploration, UniformRandomPolicy, gaussian_log_prob
from actors.trees.pendulum import build_pendulum_tree, last_tick_statuses, render_tree_ascii

SWING_UP = "actors.trees.pendulum:swing_up"
"""The Pendulum presets' ``hardcoded_policy``."""
PENDULUM = gym.make("Pendulum-v1")


def pendulum_policy() -> TreePolicy:
    """The tree the Pendulum presets name, built the way every actor builds it."""
    policy = make_hardcoded_policy(SWING_UP, PENDULUM.observation_space, PENDULUM.action_space)
    assert isinstance(policy, TreePolicy)
    return policy


def _obs(theta: float, theta_dot: float) -> np.ndarray:
    return np.array([math.cos(theta), math.sin(theta), theta_dot], dtype=np.float32)


BELOW, ABOVE = 2.8, 0.4  # radians from upright: cos < 0 and cos > 0

SIGN_CASES = [
    # (theta, theta_dot, expected torque): pump along θ̇ below, brake against θ̇ above
    pytest.param(BELOW, 1.5, 2.0, id="below-positive"),
    pytest.param(-BELOW, -1.5, -2.0, id="below-negative"),
    pytest.param(ABOVE, 1.5, -2.0, id="above-positive"),
    pytest.param(-ABOVE, -1.5, 2.0, id="above-negative"),
]


@pytest.mark.parametrize("theta, theta_dot, expected", SIGN_CASES)
def test_tree_action_sign_cases(theta: float, theta_dot: float, expected: float) -> None:
    action = pendulum_policy()(_obs(theta, theta_dot))
    assert action.shape == (1,)
    assert action.dtype == np.float32
    assert action[0] == expected


STATUS_CASES = [  # None: the node was not ticked
    pytest.param(
        BELOW,
        {
            "Swing-up": Status.SUCCESS,
            "Pump below pivot": Status.SUCCESS,
            "Below pivot?": Status.SUCCESS,
            "Pump energy": Status.SUCCESS,
            "Brake near top": None,
        },
        id="below-pumps",
    ),
    pytest.param(
        ABOVE,
        {
            "Swing-up": Status.SUCCESS,
            "Pump below pivot": Status.FAILURE,
            "Below pivot?": Status.FAILURE,
            "Pump energy": None,
            "Brake near top": Status.SUCCESS,
        },
        id="above-brakes",
    ),
]


@pytest.mark.parametrize("theta, expected", STATUS_CASES)
def test_tree_status_table_after_tick(theta: float, expected: dict[str, Status | None]) -> None:
    policy = pendulum_policy()
    # Tick the other branch first, so a leaf that ran only then must show as not ticked.
    policy(_obs(ABOVE if theta == BELOW else BELOW, 1.0))
    policy(_obs(theta, 1.0))
    assert last_tick_statuses(policy.tree) == expected


def test_batch_matches_single() -> None:
    rng = np.random.default_rng(0)
    theta = rng.uniform(-math.pi, math.pi, size=64)
    obs = np.stack([np.cos(theta), np.sin(theta), rng.uniform(-8, 8, size=64)], axis=1)
    policy = pendulum_policy()
    batch = policy(obs.astype(np.float32))
    singles = np.stack([policy(row) for row in obs.astype(np.float32)])
    assert batch.shape == (64, 1) and batch.dtype == np.float32
    np.testing.assert_array_equal(batch, singles)
    assert np.all(np.abs(batch) <= 2.0)


def test_policy_refuses_wrong_observation_shape() -> None:
    with pytest.raises(ValueError, match=r"\(2, 4\)"):
        pendulum_policy()(np.zeros((2, 4)))


def test_policy_pickles_as_its_import_string_and_rebuilds_the_tree() -> None:
    low_torque = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    policy = ImportedPolicy(SWING_UP, PENDULUM.observation_space, low_torque)
    assert policy(_obs(BELOW, 1.0))[0] == 1.0  # built here, with the box's torque
    shipped = pickle.dumps(policy)
    assert b"py_trees" not in shipped  # the tree stays behind; the string travels
    assert pickle.loads(shipped)(_obs(ABOVE, 1.0))[0] == -1.0


# Recorded from the Pendulum presets' tree (seed 0 episodes; warm-up acts on fixed
# observations): the same seeds must keep giving the same returns and the same actions.
RECORDED_RETURNS = [-522.5450591084027, -265.1920441850731, -393.71600588109175]
RECORDED_WARMUP = {
    "pendulum-backbone": (
        [2.0, -2.0, 2.0, -2.0, 1.0947014093399048, -2.0],
        {
            "action": [4.081838130950928, -5.111330032348633, 0.8361976742744446,
                       -1.135539174079895, -0.9052985906600952, -0.43119433522224426],
            "backbone_action": [2.0, 2.0, 2.0, -2.0, 2.0, -2.0],
        },
    ),
    "pendulum-td3bc": (
        [2.0, 0.7221674919128418, 2.0, -2.0, 1.7736753225326538, -2.0],
        {"backbone_action": [2.0, 2.0, 2.0, -2.0, 2.0, -2.0]},
    ),
    "pendulum-options": (
        [-1.5453119277954102, 2.0, 2.0, -2.0, 0.34719428420066833, 0.9513511657714844],
        {"option": [1, 0, 0, 0, 1, 1]},
    ),
}  # fmt: skip


def test_registered_tree_scores_what_the_old_policy_scored() -> None:
    returns = run_episodes(pendulum_policy(), episodes=3, seed=0)
    assert returns.tolist() == RECORDED_RETURNS


@pytest.mark.parametrize("preset", sorted(RECORDED_WARMUP))
def test_preset_behaviours_act_as_before(preset: str) -> None:
    from graft.config import load_preset
    from graft.registry import make_builder

    rng = np.random.default_rng(7)
    theta = rng.uniform(-np.pi, np.pi, 6)
    obs = np.stack([np.cos(theta), np.sin(theta), rng.uniform(-8, 8, 6)], 1).astype(np.float32)
    behaviour = make_builder(load_preset(preset)).make_behaviour(num_actors=2)
    action, columns = behaviour.act(obs, np.random.default_rng(3), warmup=True)
    expected_action, expected_columns = RECORDED_WARMUP[preset]
    assert action.ravel().tolist() == expected_action
    for name, values in expected_columns.items():
        assert columns[name].ravel().tolist() == values, name


def test_tree_renders_as_ascii() -> None:
    text = render_tree_ascii(build_pendulum_tree())
    for name in ("Swing-up", "Pump below pivot", "Below pivot?", "Pump energy", "Brake near top"):
        assert name in text
    policy = pendulum_policy()
    policy(_obs(ABOVE, 1.0))
    status_text = render_tree_ascii(policy.tree, show_status=True)
    assert "Below pivot? [x]" in status_text and "Brake near top [o]" in status_text


HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)

LOG_PROB_CASES = [
    # (action, mean, std, expected) hand-computed
    pytest.param([[0.5]], [[0.0]], 1.0, [-0.5 * 0.25 - HALF_LOG_2PI], id="1d-unit"),
    pytest.param([[1.0]], [[0.0]], 2.0, [-0.5 * 0.25 - math.log(2.0) - HALF_LOG_2PI], id="1d-std2"),
    pytest.param(
        [[0.5, -1.0]],
        [[0.0, 1.0]],
        1.0,
        [-0.5 * (0.25 + 4.0) - 2 * HALF_LOG_2PI],
        id="2d-unit",
    ),
    pytest.param(
        [[0.5, -1.0]],
        [[0.0, 1.0]],
        [0.5, 2.0],
        [-0.5 * (1.0 + 1.0) - math.log(0.5) - math.log(2.0) - 2 * HALF_LOG_2PI],
        id="2d-per-dim-std",
    ),
]


@pytest.mark.parametrize("action, mean, std, expected", LOG_PROB_CASES)
def test_gaussian_log_prob(action: list, mean: list, std: object, expected: list) -> None:
    got = gaussian_log_prob(np.array(action), np.array(mean), np.asarray(std))
    assert got.shape == (len(expected),)
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_gaussian_exploration_returns_unclipped_actions_and_their_log_probs() -> None:
    explore = GaussianExploration(std=3.0, low=-2.0, high=2.0)
    mean = np.full((500, 1), 1.5, dtype=np.float32)
    action, log_prob = explore.sample(mean, np.random.default_rng(0))
    assert action.shape == (500, 1) and action.dtype == np.float32
    assert np.any(action > 2.0) and np.any(action < -2.0)
    np.testing.assert_allclose(log_prob, gaussian_log_prob(action, mean, 3.0), rtol=1e-12)
    assert np.all(np.abs(explore.clip(action)) <= 2.0)


def test_gaussian_exploration_refuses_zero_std() -> None:
    with pytest.raises(ValueError, match="importance ratio"):
        GaussianExploration(std=0.0, low=-2.0, high=2.0)


def test_uniform_random_policy_log_prob() -> None:
    uniform = UniformRandomPolicy(low=np.array([-2.0, 0.0]), high=np.array([2.0, 0.5]))
    action, log_prob = uniform.sample(100, np.random.default_rng(0))
    assert action.shape == (100, 2)
    assert np.all(action >= [-2.0, 0.0]) and np.all(action <= [2.0, 0.5])
    np.testing.assert_allclose(log_prob, np.full(100, -math.log(4.0) - math.log(0.5)))


def test_run_episodes_is_deterministic_for_a_fixed_seed() -> None:
    first = run_episodes(pendulum_policy(), episodes=4, seed=3)
    second = run_episodes(pendulum_policy(), episodes=4, seed=3, num_envs=3)
    assert first.shape == (4,)
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first, run_episodes(pendulum_policy(), episodes=4, seed=4))


def test_hard_coded_policy_beats_random_by_a_wide_margin() -> None:
    # Paper sec. IV-B: hard-coded about -580, random about -1200 (we measure about -430
    # and -1200 over 100 episodes at seed 0).
    hard_coded = run_episodes(pendulum_policy(), episodes=100, seed=0).mean()
    random = run_episodes(random_policy_for("Pendulum-v1", seed=0), episodes=100, seed=0).mean()
    assert -1400.0 < random < -1000.0
    assert hard_coded > random + 300.0
