"""TD3Config (learner/td3/config.py): every field is used by someone, bad values are refused
with the field's name."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from torch import nn

from learner.td3.config import TD3Config
from learner.td3.networks import TwinCritic
from tests.learner.helpers import SMALL, flat_params, td3_batch, td3_learner

# Fields the learner step itself consumes; the rest are consumed elsewhere (named here so
# a new field forces a decision about who reads it).
LEARNER_FIELDS = {
    "gamma": 0.5,
    "tau": 0.5,
    "policy_noise": 0.0,
    "noise_clip": 0.01,
    "policy_delay": 1,
    "actor_lr": 1e-2,
    "critic_lr": 1e-2,
    "hidden_sizes": (16, 8),
    "critic_layer_norm": "first",
    "frozen_actor_updates": 2,
    "standardize_observations": True,
}


USED_ELSEWHERE = {
    "batch_size": "learner loop (replay sampling)",
    "exploration_noise": "actors",
    "burn_in_updates": "builder phases (the rate limiter's sample credit)",
}


def test_every_config_field_is_accounted_for() -> None:
    fields = {f.name for f in dataclasses.fields(TD3Config)}
    assert fields == LEARNER_FIELDS.keys() | USED_ELSEWHERE.keys()


@pytest.mark.parametrize(("field", "value"), LEARNER_FIELDS.items())
def test_every_learner_field_changes_the_update(field: str, value: object) -> None:
    def train(config: TD3Config) -> list[torch.Tensor]:
        learner = td3_learner(config)
        for i in range(4):
            learner.update(td3_batch(seed=i))
        return [flat_params(m) for m in (learner.actor, learner.critic, learner.target_critic)]

    base = train(SMALL)
    changed = train(dataclasses.replace(SMALL, **{field: value}))  # type: ignore[arg-type]
    assert any(
        a.shape != b.shape or not torch.equal(a, b) for a, b in zip(base, changed, strict=True)
    )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("gamma", 1.5),
        ("tau", 0.0),
        ("policy_noise", -0.1),
        ("noise_clip", -1.0),
        ("policy_delay", 0),
        ("actor_lr", 0.0),
        ("critic_lr", -1e-3),
        ("hidden_sizes", ()),
        ("batch_size", 0),
        ("exploration_noise", -0.1),
        ("frozen_actor_updates", -1),
        ("burn_in_updates", -1),
        ("critic_layer_norm", "every"),
    ],
)
def test_config_refuses_bad_values(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=field):
        TD3Config(**{field: value})  # type: ignore[arg-type]


def test_config_accepts_hidden_sizes_list_from_yaml() -> None:
    config = TD3Config(hidden_sizes=[32, 32])  # type: ignore[arg-type]
    assert config.hidden_sizes == (32, 32)
    hash(config)


@pytest.mark.parametrize(
    ("value", "normed"), [(False, 0), (True, 2), ("none", 0), ("first", 1), ("all", 2)]
)
def test_critic_layer_norm_puts_a_layer_norm_where_it_says(value: object, normed: int) -> None:
    """A bool (how runs recorded it before ``first``) reads as ``all`` or ``none``."""
    setting = TD3Config(critic_layer_norm=value).critic_layer_norm  # type: ignore[arg-type]
    layers = list(TwinCritic(3, 1, (8, 8), layer_norm=setting).q1_net)
    after_hidden = [layers[i + 1] for i, m in enumerate(layers[:-1]) if isinstance(m, nn.Linear)]
    assert [isinstance(m, nn.LayerNorm) for m in after_hidden] == [True] * normed + [False] * (
        2 - normed
    )
