"""`PolicyNet`, the numpy forward pass actors act with, against the learner's torch networks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from actors.policy_net import PolicyNet, TwinQ
from learner.dqn.networks import make_q_network
from learner.td3.networks import Actor, Standardize, TwinCritic, acting_copy, mlp
from service.core import as_arrays

LOW, HIGH = np.array([-2.0, 0.0], np.float32), np.array([2.0, 3.0], np.float32)


def _standardized(network: torch.nn.Module) -> torch.nn.Module:
    """`network` with its Standardize's shift and scale away from 0 and 1."""
    (standardize,) = [m for m in network.modules() if isinstance(m, Standardize)]
    n = len(standardize.shift)
    standardize.shift.copy_(torch.linspace(-2.0, 3.0, n))
    standardize.scale.copy_(torch.linspace(1.0, 9.0, n))
    return network


@pytest.mark.parametrize(
    "network",
    [
        pytest.param(lambda: Actor(5, 2, LOW, HIGH, (64, 32)), id="tanh actor, 2 hidden"),
        pytest.param(lambda: Actor(5, 2, LOW, HIGH, ()), id="tanh actor, no hidden"),
        pytest.param(lambda: make_q_network(5, 4, (16,)), id="q network"),
        pytest.param(lambda: mlp(5, (16, 8), 3, layer_norm="all"), id="with LayerNorm"),
        pytest.param(lambda: mlp(5, (16, 8), 3, layer_norm="first"), id="LayerNorm first only"),
        pytest.param(
            lambda: _standardized(Actor(5, 2, LOW, HIGH, (16,), standardized=3)),
            id="actor, 3 of 5 inputs standardized",
        ),
        pytest.param(
            lambda: _standardized(mlp(5, (16, 8), 3, layer_norm="all", standardized=5)),
            id="standardized, with LayerNorm",
        ),
    ],
)
def test_the_numpy_forward_pass_equals_torchs(network) -> None:
    torch.manual_seed(0)
    net = network()
    for p in net.parameters():  # weights large enough that every ReLU and tanh matters
        torch.nn.init.normal_(p, std=0.7)
    obs = np.random.default_rng(0).normal(size=(33, 5)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.as_tensor(obs)).numpy()
    got = acting_copy(net)(obs)
    assert got.dtype == np.float32 and got.shape == expected.shape
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)


def test_load_takes_new_weights_and_refuses_others() -> None:
    torch.manual_seed(0)
    first, second = Actor(3, 2, LOW, HIGH, (8,)), Actor(3, 2, LOW, HIGH, (8,))
    acting = acting_copy(first)
    acting.load(as_arrays(second.state_dict()))
    obs = np.ones((1, 3), np.float32)
    with torch.no_grad():
        np.testing.assert_allclose(acting(obs), second(torch.as_tensor(obs)).numpy(), atol=1e-6)
    wider = as_arrays(Actor(3, 2, LOW, HIGH, (9,)).state_dict())
    with pytest.raises(ValueError, match="do not fit"):
        acting.load(wider)
    with pytest.raises(ValueError, match="do not fit"):
        acting.load({k: v for k, v in as_arrays(second.state_dict()).items() if k != "net.0.bias"})


@pytest.mark.parametrize(
    "weights, error",
    [
        ({"conv.weight": np.ones((2, 2))}, "not a linear layer's"),
        ({"0.weight": np.ones((2, 2))}, "weight and a bias"),
        ({}, "weight and a bias"),
        (
            {
                f"q{i}_net.0.{part}": np.ones((2, 2) if part == "weight" else 2)
                for i in (1, 2)
                for part in ("weight", "bias")
            },
            "more than one network",
        ),  # fmt: skip
        (
            {"0.weight": np.ones((2, 2)), "0.bias": np.ones(2), "action_low": np.zeros(2)},
            "both",
        ),
        ({"0.weight": np.ones(2), "0.bias": np.ones(2)}, "must follow a linear layer"),
    ],
)
def test_weights_that_are_not_an_mlp_are_refused(weights, error) -> None:
    with pytest.raises(ValueError, match=error):
        PolicyNet(weights)


def test_layers_run_in_index_order_not_name_order() -> None:
    # "net.10" sorts before "net.2" as text: a network of 6+ layers must still chain.
    layers = [np.full((2, 2), float(i + 1), np.float32) for i in range(6)]
    weights = {}
    for i, w in enumerate(layers):
        weights[f"net.{2 * i}.weight"], weights[f"net.{2 * i}.bias"] = w, np.zeros(2, np.float32)
    out = PolicyNet(weights)(np.ones((1, 2), np.float32))
    expected = np.ones((1, 2), np.float32)
    for w in layers:
        expected = expected @ w.T  # all positive: the ReLUs pass everything
    np.testing.assert_allclose(out, expected)


@pytest.mark.parametrize(
    ("layer_norm", "standardized"), [("none", 0), ("first", 0), ("all", 0), ("all", 4)]
)
def test_the_twin_critic_in_numpy_is_the_smaller_of_torchs_two_estimates(
    layer_norm, standardized
) -> None:
    torch.manual_seed(0)
    critic = TwinCritic(4, 2, (16, 16), layer_norm=layer_norm, standardized=standardized)
    if standardized:
        _standardized(critic.q1_net), _standardized(critic.q2_net)
    for p in critic.parameters():  # LayerNorm's scale and shift away from 1 and 0 too
        torch.nn.init.normal_(p, std=0.7)
    rng = np.random.default_rng(0)
    x = rng.normal(size=(9, 4)).astype(np.float32)
    a = rng.normal(size=(9, 2)).astype(np.float32)
    with torch.no_grad():
        expected = torch.min(*critic(torch.as_tensor(x), torch.as_tensor(a))).numpy()
    twin = TwinQ(as_arrays(critic.state_dict()))
    np.testing.assert_allclose(twin(x, a), expected, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="q1_net"):
        twin.load({**as_arrays(critic.state_dict()), "extra.0.weight": np.ones((1, 1))})


def test_an_acting_copy_keeps_its_weights_when_the_network_trains_on() -> None:
    torch.manual_seed(0)
    net = Actor(3, 2, LOW, HIGH, (8,))
    acting = acting_copy(net)
    obs = np.ones((1, 3), np.float32)
    before = acting(obs)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(1.0)  # the learner's in-place update
    np.testing.assert_array_equal(acting(obs), before)
