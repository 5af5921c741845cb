"""Every algorithm's behaviour keeps the `Behaviour` contract (service/core.py): the
columns it returns, from `act` and from `next_columns`, are the ones it declares."""

from __future__ import annotations

import numpy as np
import pytest

from graft.config import load_preset
from graft.registry import make_builder

BEHAVIOURS = [
    # (preset, overrides, the columns it computes on s')
    ("pendulum-td3", {}, set()),
    ("pendulum-pretrained-td3", {}, set()),
    ("pendulum-backbone", {"backbone.observe_backbone": False}, set()),
    ("pendulum-backbone", {"backbone.observe_backbone": True}, {"next_backbone_action"}),
    ("pendulum-options", {}, set()),
    ("cartpole-ddqn", {}, set()),
]


@pytest.mark.parametrize("preset, overrides, next_state_columns", BEHAVIOURS)
@pytest.mark.parametrize("warmup", [True, False])
def test_a_behaviour_returns_exactly_the_columns_it_declares(
    preset, overrides, next_state_columns, warmup
):
    config = load_preset(preset, **overrides)
    behaviour = make_builder(config).make_behaviour(num_actors=1)
    env = config.make_env()
    space = env.observation_space
    env.close()
    space.seed(0)
    obs = np.stack([space.sample() for _ in range(3)]).astype(np.float32)
    next_obs = np.stack([space.sample() for _ in range(3)]).astype(np.float32)

    _, columns = behaviour.act(obs, np.random.default_rng(0), warmup=warmup)
    after = behaviour.next_columns(next_obs)

    # A behaviour without next-state columns contributes none to the actor's record.
    assert set(after) == next_state_columns
    declared = behaviour.columns()
    assert set(columns) | set(after) == set(declared)
    assert not set(columns) & set(after)
    for name, array in {**columns, **after}.items():
        spec = declared[name]
        assert array.dtype == np.dtype(spec["dtype"]), name
        assert array.shape == (3, *spec["shape"]), name
