"""A Malmo mission as a gymnasium environment, against a real world server: the encoding
by hand, the commands an action becomes, the world clock in ``info``, the mission's time
limit as truncation, and a world server going away as ``ConnectionError``."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from minecraft.agent.mission_env import (
    ENV_ID,
    action_commands,
    encode_observation,
    observation_space,
)
from minecraft.malmo.mission import parse_mission
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.server import WorldServer
from tests.minecraft.conftest import FAST, flat_mission

MISSION = flat_mission(grid_radius=1, ms_per_tick=20)
OBS_DIM = 8 + 27


def test_encoding_hand_computed() -> None:
    mission = parse_mission(MISSION)
    assert observation_space(mission).shape == (OBS_DIM,)
    grid = ["stone"] * 9 + ["air"] * 9 + ["water"] * 8 + ["stone_slab"]  # unknown: solid
    info = {"XPos": 32.0, "YPos": 64.0, "ZPos": -16.0, "Yaw": 90.0, "Pitch": 45.0}
    info |= {"Life": 10.0, "Food": 20, "TotalTime": 3, "cube": grid}
    v = encode_observation(info, mission)
    expected = [0.5, 1.0, -0.25, 1.0, 0.0, 0.5, 0.5, 1.0] + [1] * 9 + [0] * 17 + [1]
    assert v.dtype == np.float32
    np.testing.assert_allclose(v, expected, atol=1e-6)
    with pytest.raises(ValueError, match="cells"):
        encode_observation({**info, "cube": grid[:-1]}, mission)
    with pytest.raises(ValueError, match="ObservationFromFullStats"):
        observation_space(parse_mission(mission_xml(width=None, observations="")))


def test_action_commands_clip_and_threshold() -> None:
    text = action_commands(np.array([2.0, -0.5, 0.0, 0.25, 0.1, -0.3]))
    assert text == "move 1.000\nstrafe -0.500\nturn 0.000\npitch 0.250\njump 1\nattack 0"


def test_ticks_in_info_and_the_time_limit_truncates(server: WorldServer) -> None:
    env = gym.make(
        ENV_ID,
        address=f"127.0.0.1:{server.port}",
        mission_xml=flat_mission(grid_radius=1, time_limit_ms=500),  # 10 ticks of game time
        real_time=False,
    )
    obs, info = env.reset(seed=0)
    assert obs.shape == (OBS_DIM,) and env.observation_space.contains(obs)
    ticks, endings = [info["tick"]], []
    while not endings or endings[-1] == (False, False):
        obs, reward, terminated, truncated, info = env.step(np.zeros(6, np.float32))
        ticks.append(info["tick"])
        endings.append((terminated, truncated))
    assert np.diff(ticks).tolist() == [1] * len(endings)  # synchronous: a tick a step
    assert ticks[-1] == 10 and endings[-1] == (False, True)  # time up: truncated
    env.close()


@pytest.mark.serial  # real-time pacing: a starved world server misses its ticks
def test_a_real_time_step_ends_at_a_new_tick_and_keeps_every_reward() -> None:
    """Frames come at 60/s and ticks at 20/s: a step landing between two ticks waits for
    the next tick's observation instead of returning the same world again, and the
    rewards of the steps it took meanwhile are summed into its own."""
    per_tick = '<RewardForTimeTaken initialReward="0" delta="-1" density="PER_TICK"/>'
    with WorldServer(port=0, seed=7, ms_per_tick=50, timing=FAST) as server:
        env = gym.make(
            ENV_ID,
            address=f"127.0.0.1:{server.port}",
            mission_xml=flat_mission(grid_radius=1, ms_per_tick=50, rewards=per_tick),
        )
        _, info = env.reset(seed=0)
        ticks, rewards = [info["tick"]], []
        for _ in range(20):
            _, reward, *_, info = env.step(np.zeros(6, np.float32))
            ticks.append(info["tick"])
            rewards.append(reward)
        env.close()
    assert all(np.diff(ticks) >= 1), ticks  # every step brings a newer tick
    # -1 a tick; a tick's reward may come one reply before its observation does.
    assert abs(sum(rewards) + (ticks[-1] - ticks[0])) <= 1, (ticks, rewards)


def test_a_world_server_going_away_is_a_connection_error() -> None:
    server = WorldServer(port=0, seed=7, ms_per_tick=20)
    server.start()
    env = gym.make(ENV_ID, address=f"127.0.0.1:{server.port}", mission_xml=MISSION)
    env.reset()
    env.step(np.zeros(6, np.float32))
    server.stop()
    with pytest.raises(ConnectionError, match=str(server.port)):
        for _ in range(5):  # the reply in flight may still arrive
            env.step(np.zeros(6, np.float32))
    with pytest.raises(ConnectionError):
        env.reset()
    env.close()
