"""bench/pendulum_ceiling.py: its model is Pendulum-v1's step, and its controller plays the
real environment well (the bound it reports is a return a policy reaches)."""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
import pendulum_ceiling as ceiling  # noqa: E402


def test_the_model_step_is_pendulums_own():
    env = gym.make("Pendulum-v1").unwrapped
    rng = np.random.default_rng(0)
    for _ in range(50):
        theta, speed, torque = rng.uniform(-4, 4), rng.uniform(-8, 8), rng.uniform(-2, 2)
        env.state = np.array([theta, speed])
        _, reward, *_ = env.step(np.array([torque], np.float32))
        theta2, speed2, model_reward = ceiling.model_step(
            np.array([theta]), np.array([speed]), np.array([np.float32(torque)], np.float64)
        )
        np.testing.assert_allclose([theta2[0], speed2[0], model_reward[0]],
                                   [*env.state, reward], rtol=1e-5, atol=1e-5)  # fmt: skip


def test_the_controller_swings_up_and_holds_on_the_real_environment():
    grid = ceiling.Grid(120, 81)  # coarse: a lower bound still, in a second
    values = ceiling.solve(grid, np.linspace(-2.0, 2.0, 11))
    returns = ceiling.play(grid, values, seed=100_000, episodes=3)
    # The swing-up tree scores about -440 on these episodes; a hanging pendulum about -1,300.
    assert (returns > -300.0).all(), returns
