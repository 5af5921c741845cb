"""The simulated environment: the stood-in task's spaces, its step costs and its clock."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np
import pytest

from actors.simulated import SimulatedEnv, busy_wait, simulated_env_kwargs
from actors.tick_meter import TickMeter


def test_it_has_the_stood_in_tasks_spaces_and_episode_limit():
    real = gym.make("Pendulum-v1")
    env = SimulatedEnv(**simulated_env_kwargs(real))
    assert env.observation_space == real.observation_space
    assert env.action_space == real.action_space
    obs, _ = env.reset()
    assert obs.shape == (3,) and real.observation_space.contains(obs)
    ends = [env.step(env.action_space.sample())[3] for _ in range(200)]
    assert ends == [False] * 199 + [True]  # Pendulum's 200-step time limit


def test_busy_wait_spends_cpu_time():
    t0 = time.thread_time()
    busy_wait(0.02)
    assert time.thread_time() - t0 >= 0.02


def test_rate_cap_paces_steps():
    env = SimulatedEnv(observation_space=gym.spaces.Box(-1, 1, (2,)),
                       action_space=gym.spaces.Discrete(2), steps_per_s=100.0)  # fmt: skip
    env.reset()
    t0 = time.monotonic()
    for _ in range(11):
        env.step(0)
    assert time.monotonic() - t0 >= 0.1  # 10 periods of 10 ms after the first step


def test_real_time_mode_reports_the_ticks_a_slow_actor_skipped():
    env = SimulatedEnv(observation_space=gym.spaces.Box(-1, 1, (2,)),
                       action_space=gym.spaces.Discrete(2), tick_ms=20.0)  # fmt: skip
    meter = TickMeter(1)
    _, info = env.reset()
    meter.begin(0, info["tick"])
    for _ in range(5):  # keeping up: every tick seen
        meter.step(0, env.step(0)[4]["tick"], 0.0)
    assert meter.skipped == 0 and meter.seen == 6
    time.sleep(0.1)  # five ticks pass unobserved
    skipped = meter.step(0, env.step(0)[4]["tick"], 0.1)
    assert skipped >= 4


@pytest.mark.parametrize("bad", [{"cpu_ms": -1.0}, {"tick_ms": float("nan")}, {"episode_steps": 0}])
def test_bad_costs_are_refused(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        SimulatedEnv(observation_space=gym.spaces.Box(-1, 1, (2,)),
                     action_space=gym.spaces.Discrete(2), **bad)  # fmt: skip


def test_observations_are_drawn_inside_finite_bounds():
    space = gym.spaces.Box(np.array([0.0, -np.inf]), np.array([1.0, np.inf]), dtype=np.float32)
    env = SimulatedEnv(observation_space=space, action_space=gym.spaces.Discrete(2))
    obs = np.stack([env.step(0)[0] for _ in range(32)])
    assert obs.dtype == np.float32 and (obs[:, 0] >= 0).all() and (obs[:, 0] <= 1).all()
