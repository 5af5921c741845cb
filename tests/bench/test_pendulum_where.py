"""bench/pendulum_where.py: an episode's swing-up and top add up to its return, and the
balancing statistics tell a steady hold from a chattering one."""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
import pendulum_where as where  # noqa: E402


def _steady(obs: np.ndarray) -> np.ndarray:
    """Energy pumping far from the top, a PD hold near it: arrives, then holds still."""
    cos, sin, speed = obs[:, 0], obs[:, 1], obs[:, 2]
    angle = np.arctan2(sin, cos)
    hold = -10.0 * angle - 2.0 * speed
    pump = 2.0 * np.sign(speed * (0.5 * speed**2 + 15.0 * (cos - 1.0)) * -1.0 + 1e-9)
    return np.clip(np.where(cos > 0.8, hold, pump), -2.0, 2.0)[:, None]


def _chattering(obs: np.ndarray) -> np.ndarray:
    """The same, holding with full torque of the PD's sign: bang-bang at the top."""
    action = _steady(obs)
    return np.where(obs[:, :1] > 0.8, 2.0 * np.sign(action), action)


def test_the_phases_add_up_to_each_episodes_own_return():
    played = where.play(_steady, first_reset=100_000, episodes=4)
    returns = []
    for i in range(4):
        env = gym.make("Pendulum-v1")
        obs, _ = env.reset(seed=100_000 + i)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(_steady(obs[None])[0])
            total, done = total + reward, terminated or truncated
        returns.append(total)
    np.testing.assert_allclose(played["return"], returns, rtol=1e-6)
    np.testing.assert_allclose(played["swing"] + played["top"], played["return"], rtol=1e-6)


def test_the_balancing_statistics_tell_a_steady_hold_from_a_chattering_one():
    steady = where.play(_steady, first_reset=100_000, episodes=4)
    chattering = where.play(_chattering, first_reset=100_000, episodes=4)
    assert np.nanmean(steady["torque"]) < 0.2 < 1.5 < np.nanmean(chattering["torque"])
    assert np.nanmean(steady["flips"]) < 0.2 < np.nanmean(chattering["flips"])
    assert np.nanmean(steady["top"]) > np.nanmean(chattering["top"])
