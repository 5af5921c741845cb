"""Each method refuses, in one line naming the space, a task it cannot handle."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from gymnasium import spaces

from learner.spaces import box_action_dim, discrete_actions, observation_dim

FLAT = spaces.Box(-1.0, 1.0, (3,), np.float32)
BOX = spaces.Box(-2.0, 2.0, (1,), np.float32)

REFUSALS = [
    (
        lambda: box_action_dim(spaces.Discrete(3), "backbone_td3"),
        "backbone_td3 needs continuous actions (a 1-D Box), the environment's action space "
        "is Discrete(3): use algorithm ddqn for discrete actions",
    ),
    (
        lambda: discrete_actions(BOX, "ddqn"),
        "ddqn needs a Discrete action space, the environment's is Box(-2.0, 2.0, (1,), "
        "float32): use a TD3-family algorithm (td3, backbone_td3, pretrain_td3, options) for "
        "continuous actions",
    ),
    (
        lambda: observation_dim(spaces.Dict({"x": FLAT}), "td3"),
        "td3 needs a flat (1-D) Box observation space, the environment's is Dict('x': "
        "Box(-1.0, 1.0, (3,), float32)): set obs_wrapper to a wrapper that flattens or encodes "
        "it (e.g. obs_wrapper: gymnasium.wrappers:FlattenObservation)",
    ),
    (
        lambda: observation_dim(spaces.Box(0, 255, (8, 8, 3), np.uint8), "ddqn"),
        "ddqn needs a flat (1-D) Box observation space, the environment's is Box(0, 255, "
        "(8, 8, 3), uint8): set obs_wrapper",
    ),
    (
        lambda: box_action_dim(spaces.Box(-np.inf, np.inf, (2,), np.float32), "td3"),
        "td3 needs finite action bounds, the environment's action space is Box(-inf, inf, "
        "(2,), float32): wrap it",
    ),
]


@pytest.mark.parametrize("refuse, message", REFUSALS, ids=range(len(REFUSALS)))
def test_refusal_names_the_method_and_the_space(refuse, message: str) -> None:
    with pytest.raises(ValueError) as error:
        refuse()
    assert str(error.value).startswith(message)
    assert "\n" not in str(error.value)


def test_spaces_each_method_handles() -> None:
    assert observation_dim(FLAT, "td3") == 3
    assert box_action_dim(BOX, "td3") == 1
    assert discrete_actions(spaces.Discrete(4), "ddqn") == 4


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"env_id": "CartPole-v1", "algorithm": "td3"}, "td3 needs continuous actions"),
        ({"env_id": "Pendulum-v1", "algorithm": "ddqn"}, "ddqn needs a Discrete action space"),
        (
            {"env_id": "CartPole-v1", "algorithm": "options"},
            "options needs continuous actions",
        ),
        (
            {"algorithm": "backbone_td3", "hardcoded_policy": None},
            "backbone_td3 improves a hard-coded policy, and the preset names none",
        ),
        (
            {"algorithm": "pretrain_td3", "hardcoded_policy": "actors.trees.pendulum:nope"},
            "hardcoded_policy='actors.trees.pendulum:nope': module actors.trees.pendulum has no",
        ),
    ],
)
def test_builder_refuses_a_task_before_anything_starts(overrides, message: str) -> None:
    from graft.config import load_preset
    from graft.registry import make_builder

    config = load_preset("pendulum-td3")
    config = dataclasses.replace(config, **overrides)  # None unsets the preset's policy
    with pytest.raises(ValueError, match=message):
        make_builder(config)
