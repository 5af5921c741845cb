"""The drops decision as an environment: the whole tree in a seeded world, paused at each
new wanted item in reach; the return is minus the game time it took."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from minecraft.agent.corrections import DROP_OBS_DIM
from minecraft.agent.drop_env import ENV_ID, ChaseEveryDrop


def test_the_tree_chases_every_drop() -> None:
    np.testing.assert_array_equal(ChaseEveryDrop()(np.ones((3, DROP_OBS_DIM))), [0, 0, 0])


@pytest.mark.service  # a world server (in-process)
def test_an_episode_pays_the_game_time_and_is_truncated_at_its_limit() -> None:
    env = gym.make(ENV_ID, world_seeds=(2000,), max_ticks=400)
    try:
        obs, info = env.reset(seed=0)
        first, total, steps, left = info["tick"], 0.0, 0, 0
        assert obs.shape == (DROP_OBS_DIM,) and obs[:8].sum() == 1.0  # one item, one-hot
        while True:
            action = steps % 2  # chase, leave, chase, ...
            obs, reward, terminated, truncated, info = env.step(action)
            total, steps, left = total + reward, steps + 1, left + action
            assert reward <= 0.0
            if terminated or truncated:
                break
        assert truncated and not terminated and not info["diamond"]
        assert total == pytest.approx(-(info["ticks"] - first) / 100.0)
        result = env.unwrapped.episode.result()
        assert result.drops_decided == steps and result.drops_left == left
    finally:
        env.close()
