"""The hard-coded Acrobot tree (a held-out task of bench/improve.py): energy pumping."""

import gymnasium as gym
import numpy as np
import pytest

from actors.evaluator import run_episodes
from actors.hardcoded import make_hardcoded_policy

ACROBOT = gym.make("Acrobot-v1")


def pump():
    return make_hardcoded_policy(
        "actors.trees.acrobot:pump", ACROBOT.observation_space, ACROBOT.action_space
    )


@pytest.mark.parametrize(
    "theta2_dot, expected", [(0.5, 2), (-0.5, 0), (0.0, 0), (1e-3, 2)]
)  # torque +1 while the lower link turns +, else −1
def test_the_tree_pushes_the_lower_link_the_way_it_turns(theta2_dot, expected):
    obs = np.array([1.0, 0.0, 1.0, 0.0, -2.0, theta2_dot], np.float32)
    assert int(np.asarray(pump()(obs))) == expected


def test_the_tree_swings_the_tip_up_well_before_the_time_limit():
    returns = run_episodes(pump(), env="Acrobot-v1", episodes=5, seed=100_000)
    assert all(-300.0 < r < -50.0 for r in returns)  # −1 a step; −500 never reached
