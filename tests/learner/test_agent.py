"""A builder's phases carry the learning step their batches go to."""

from __future__ import annotations

import pytest
import torch

from graft.config import load_preset
from graft.registry import make_builder
from learner.agent import update_step
from learner.pretrain.learning import pretrain_step


def pendulum_batch(n: int = 8) -> dict[str, torch.Tensor]:
    return {
        "obs": torch.zeros(n, 3),
        "action": torch.zeros(n, 1),
        "backbone_action": torch.ones(n, 1),
        "reward": torch.ones(n),
        "terminated": torch.zeros(n, dtype=torch.bool),
        "next_obs": torch.zeros(n, 3),
    }


def test_pre_training_steps_on_demonstrations_then_updates_online():
    builder = make_builder(load_preset("pendulum-pretrained-td3"))
    demos, online = builder.phases()
    assert (demos.step, online.step) == (pretrain_step, update_step)
    learner = builder.make_learner()
    demos.step(learner, pendulum_batch())
    assert (learner.num_pretrain_updates, learner.num_updates) == (1, 0)
    online.step(learner, pendulum_batch())
    assert (learner.num_pretrain_updates, learner.num_updates) == (1, 1)


def test_a_pre_training_step_refuses_an_algorithm_that_cannot_pre_train():
    td3 = make_builder(load_preset("pendulum-td3")).make_learner()
    with pytest.raises(TypeError, match="PretrainLearner, got TD3Learner"):
        pretrain_step(td3, pendulum_batch())
