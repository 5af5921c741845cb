"""TD3's networks and builder (learner/td3/networks.py, builder.py): bounds, heads, the
broadcast policy state and the spaces TD3 refuses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from gymnasium import spaces
from torch import nn

from actors.policy_net import PolicyNet
from learner.agent import Budget
from learner.td3.builder import (
    TD3Builder,
    critic_layer_norm_for,
    make_actor_network,
    make_td3_learner,
)
from learner.td3.networks import Actor, Standardize, TwinCritic, saved_layout
from service.core import as_arrays
from tests.learner.helpers import ACT_DIM, HIGH, LOW, OBS_DIM, SMALL, td3_batch, td3_learner

# --- networks -------------------------------------------------------------------------


def test_actor_rescales_tanh_into_bounds() -> None:
    actor = Actor(OBS_DIM, ACT_DIM, LOW, HIGH, hidden_sizes=(4,))
    for p in actor.parameters():
        nn.init.zeros_(p)
    last = actor.net[-1]
    assert isinstance(last, nn.Linear)
    last.bias.data = torch.tensor([0.0, 100.0])  # tanh -> 0 and 1
    out = actor(torch.randn(5, OBS_DIM))
    torch.testing.assert_close(out, torch.tensor([[1.0, 1.0]]).expand(5, -1))
    with torch.no_grad():
        last.bias.data = torch.tensor([-100.0, 0.0])
        torch.testing.assert_close(actor(torch.zeros(1, OBS_DIM)), torch.tensor([[-1.0, 0.5]]))


def test_twin_critic_shapes_and_q1_head() -> None:
    critic = TwinCritic(OBS_DIM, ACT_DIM, hidden_sizes=(8,))
    obs, act = torch.randn(7, OBS_DIM), torch.randn(7, ACT_DIM)
    q1, q2 = critic(obs, act)
    assert q1.shape == q2.shape == (7,)
    assert torch.equal(critic.q1(obs, act), q1)
    assert not torch.equal(q1, q2)


@pytest.mark.parametrize(
    ("low", "high"),
    [([-1.0, -np.inf], [1.0, 1.0]), ([1.0, 0.0], [1.0, 1.0]), ([-1.0], [1.0])],
    ids=["unbounded", "empty", "wrong_shape"],
)
def test_actor_refuses_bad_bounds(low: list[float], high: list[float]) -> None:
    with pytest.raises(ValueError, match="action bounds"):
        Actor(OBS_DIM, ACT_DIM, np.array(low), np.array(high), hidden_sizes=(4,))


# --- builder --------------------------------------------------------------------------


def test_act_and_policy_state_roundtrip_through_builder() -> None:
    obs_space = spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,), dtype=np.float32)
    action_space = spaces.Box(LOW, HIGH, dtype=np.float32)
    learner = make_td3_learner(obs_space, action_space, SMALL, seed=0)
    state = learner.policy_state()
    assert all(v.device.type == "cpu" and not v.requires_grad for v in state.values())

    actor = make_actor_network(OBS_DIM, ACT_DIM, LOW, HIGH, SMALL)
    actor.load_state_dict(state)
    obs = np.random.default_rng(0).normal(size=(4, OBS_DIM)).astype(np.float32)
    action = learner.act(obs)
    assert action.shape == (4, ACT_DIM) and action.dtype == np.float32
    assert ((action >= LOW) & (action <= HIGH)).all()
    with torch.no_grad():
        np.testing.assert_array_equal(actor(torch.from_numpy(obs)).numpy(), action)
    assert learner.act(obs[0]).shape == (ACT_DIM,)
    learner.update(td3_batch())  # the broadcast copy does not alias live weights
    assert all(torch.equal(v, actor.state_dict()[k]) for k, v in state.items())


@pytest.mark.parametrize(
    ("obs_space", "action_space"),
    [
        (spaces.Discrete(3), spaces.Box(-1.0, 1.0, shape=(1,))),
        (spaces.Box(-1.0, 1.0, shape=(2, 2)), spaces.Box(-1.0, 1.0, shape=(1,))),
        (spaces.Box(-1.0, 1.0, shape=(2,)), spaces.Discrete(2)),
        (spaces.Box(-1.0, 1.0, shape=(2,)), spaces.Box(-np.inf, np.inf, shape=(1,))),
    ],
    ids=["discrete_obs", "image_obs", "discrete_action", "unbounded_action"],
)
def test_builder_refuses_spaces_td3_cannot_handle(
    obs_space: spaces.Space, action_space: spaces.Space
) -> None:
    with pytest.raises(ValueError):
        make_td3_learner(obs_space, action_space, SMALL, seed=0)


@pytest.mark.parametrize(
    ("low", "high", "resolved"),
    [
        (-np.inf, np.inf, "all"),  # MuJoCo's observations: no stated scale
        ([-1.0, -np.inf, -1.0], [1.0, 1.0, 1.0], "all"),  # one open bound is enough
        (-8.0, 8.0, "none"),  # Pendulum's, LunarLander's, MountainCar's: every bound finite
    ],
)
def test_auto_layer_norm_follows_the_observation_bounds(low, high, resolved: str) -> None:
    """``critic_layer_norm: auto`` is resolved once, against the observation space, for the
    learner's critics and for the copy its behaviour switches by."""
    low, high = np.broadcast_to(low, 3), np.broadcast_to(high, 3)
    obs_space = spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
    action_space = spaces.Box(LOW, HIGH, dtype=np.float32)
    assert critic_layer_norm_for("auto", obs_space) == resolved
    assert critic_layer_norm_for("first", obs_space) == "first"  # a setting of its own stays
    config = dataclasses.replace(SMALL, critic_layer_norm="auto")
    builder = TD3Builder(
        obs_space, action_space, config=config, budget=Budget(100, 10, 1.0, 0), seed=0
    )
    assert builder.config.critic_layer_norm == resolved
    learner = builder.make_learner()
    assert any(isinstance(m, nn.LayerNorm) for m in learner.critic.modules()) == (resolved == "all")
    with pytest.raises(ValueError, match="resolved against the observation space"):
        TwinCritic(3, 2, (8,), layer_norm="auto")


@pytest.mark.parametrize("layer_norm", ["none", "first", "all"])
@pytest.mark.parametrize("hidden", [(8,), (8, 6, 4)])
def test_a_saved_critic_says_its_widths_and_where_its_layer_norms_are(layer_norm, hidden):
    """How a teacher is rebuilt from its weights alone, whatever its run recorded."""
    q1 = TwinCritic(3, 2, hidden, layer_norm=layer_norm).q1_net.state_dict()
    expected = "all" if layer_norm == "first" and len(hidden) == 1 else layer_norm
    assert saved_layout(q1) == (hidden, expected)
    actor = Actor(3, 2, np.full(2, -1.0), np.ones(2), hidden).state_dict()
    assert saved_layout(actor) == (hidden, "none")


# --- standardized observations ----------------------------------------------------------


def _standardizers(learner) -> list[Standardize]:
    networks = (learner.actor, learner.critic, learner.target_actor, learner.target_critic)
    return [m for n in networks for m in n.modules() if isinstance(m, Standardize)]


def test_standardize_observations_fits_every_network_on_the_first_batch_and_keeps_it():
    """Each observation feature centred on its mean and divided by its std where that
    exceeds 1, both from the first batch trained on, in the actor, the critics and their
    targets; fixed from then on, published with the weights and kept through a resume."""
    learner = td3_learner(dataclasses.replace(SMALL, standardize_observations=True))
    found = _standardizers(learner)
    assert len(found) == 6  # actor, two critics, and the same in the targets
    assert all(torch.equal(m.shift, torch.zeros(OBS_DIM)) for m in found)  # identity first
    first = td3_batch(n=256, seed=0)
    first["obs"] = first["obs"] * torch.tensor([20.0, 0.5, 3.0]) + torch.tensor([5.0, -1.0, 0.0])
    learner.update(first)
    shift, std = first["obs"].mean(dim=0), first["obs"].std(dim=0, correction=0)
    assert std[0] > 15 and std[1] < 1  # a wide feature is scaled, a narrow one only centred
    for m in found:
        torch.testing.assert_close(m.shift, shift)
        torch.testing.assert_close(m.scale, torch.stack([std[0], torch.tensor(1.0), std[2]]))
    learner.update(td3_batch(n=256, seed=1))  # other data: the statistics stay
    assert all(torch.equal(m.shift, shift) for m in _standardizers(learner))
    # The critics standardize the observation only, not the action after it.
    assert learner.critic.q1_net[0].shift.shape == (OBS_DIM,)

    obs = first["obs"][:7].numpy()
    np.testing.assert_allclose(
        PolicyNet(as_arrays(learner.policy_state()))(obs), learner.act(obs), rtol=1e-5, atol=1e-5
    )
    resumed = td3_learner(dataclasses.replace(SMALL, standardize_observations=True), seed=5)
    resumed.load_state_dict(learner.state_dict())
    resumed.update(td3_batch(n=256, seed=2))  # a resumed learner does not fit again
    assert resumed.standardizers_fitted
    assert all(torch.equal(m.shift, shift) for m in _standardizers(resumed))


def test_without_standardize_observations_the_networks_are_as_before():
    learner = td3_learner()
    assert not _standardizers(learner) and learner.standardizers_fitted
    assert not any(k.endswith(("shift", "scale")) for k in learner.policy_state())
