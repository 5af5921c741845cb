"""TD3's learning step (learner/td3/learning.py): hand-computed targets and losses, the update
schedule, truncation and resume."""

from __future__ import annotations

import dataclasses
import io

import numpy as np
import pytest
import torch
from torch import nn

from learner.td3.config import TD3Config
from learner.td3.learning import actor_loss, critic_loss, soft_update, td3_target
from tests.learner.helpers import (
    ACT_DIM,
    HIGH,
    LOW,
    SMALL,
    flat_params,
    td3_batch,
    td3_learner,
)

# --- hand-made "networks" with known outputs ------------------------------------------


class ScaledActor(nn.Module):
    """pi(s) = w * s (first act_dim features), no squashing: outputs can leave the box."""

    def __init__(self, w: float = 0.5) -> None:
        super().__init__()
        self.w = nn.Parameter(torch.tensor(w))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.w * obs


class ConstantActor(nn.Module):
    """pi(s) = a fixed action for every state."""

    action: torch.Tensor

    def __init__(self, action: np.ndarray) -> None:
        super().__init__()
        self.register_buffer("action", torch.as_tensor(action))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.action.expand(obs.shape[0], -1)


class HandCritic(nn.Module):
    """Q1(s, a) = s + a and Q2(s, a) = s + 2a, summed over features; records its inputs."""

    def __init__(self) -> None:
        super().__init__()
        self.seen_actions: list[torch.Tensor] = []

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        self.seen_actions.append(act.detach().clone())
        return (obs + act).sum(-1), (obs + 2 * act).sum(-1)

    def q1(self, obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        return (obs * act).sum(-1)


# --- td3_target, eq. (5) --------------------------------------------------------------


# 1-D case, gamma = 0.9, bounds [-1, 1], pi'(s') = s'/2, Q1' = s' + a', Q2' = s' + 2a'.
TARGET_CASES = [
    # id, r, s', terminated, y
    ("bootstrap", 1.0, 1.0, False, 1.0 + 0.9 * min(1.5, 2.0)),  # a' = .5 -> 2.35
    ("terminated_no_bootstrap", 1.0, 1.0, True, 1.0),
    # A truncated (time-limit) step is not terminated: s' still bootstraps.
    ("truncated_bootstraps", -1.0, -2.0, False, -1.0 + 0.9 * min(-3.0, -4.0)),  # -4.6
    ("next_action_clipped", 0.0, 4.0, False, 0.9 * min(5.0, 6.0)),  # a' = 2 -> 1
]


@pytest.mark.parametrize(("r", "s_next", "terminated", "expected"), [c[1:] for c in TARGET_CASES])
def test_td3_target_hand_values(r: float, s_next: float, terminated: bool, expected: float) -> None:
    y = td3_target(
        torch.tensor([r]),
        torch.tensor([terminated]),
        torch.tensor([[s_next]]),
        gamma=0.9,
        target_actor=ScaledActor(0.5),
        target_critic=HandCritic(),
        policy_noise=0.0,
        noise_clip=0.5,
        action_low=torch.tensor([-1.0]),
        action_high=torch.tensor([1.0]),
    )
    assert y.shape == (1,)
    assert y.item() == pytest.approx(expected)
    assert not y.requires_grad


@pytest.mark.parametrize("where", ["centre", "low", "high"])
def test_smoothing_noise_is_clipped_and_action_stays_in_bounds(where: str) -> None:
    low, high = torch.as_tensor(LOW), torch.as_tensor(HIGH)
    max_action = (high - low) / 2  # [2.0, 0.5]
    mean = {"centre": (low + high) / 2, "low": low, "high": high}[where]
    critic = HandCritic()
    td3_target(
        torch.zeros(4096),
        torch.zeros(4096, dtype=torch.bool),
        torch.zeros(4096, ACT_DIM),
        gamma=0.99,
        target_actor=ConstantActor(mean.numpy()),
        target_critic=critic,
        policy_noise=100.0,  # huge: nearly every draw hits the clip
        noise_clip=0.5,
        action_low=low,
        action_high=high,
        generator=torch.Generator().manual_seed(0),
    )
    (a_next,) = critic.seen_actions
    assert (a_next >= low).all() and (a_next <= high).all()
    noise = a_next - mean
    assert (noise.abs() <= 0.5 * max_action + 1e-6).all()
    if where == "centre":  # the clip is reached on both sides
        assert torch.allclose(noise.abs().amax(0), 0.5 * max_action)


def test_smoothing_noise_std_is_a_fraction_of_max_action() -> None:
    low, high = torch.as_tensor(LOW), torch.as_tensor(HIGH)
    centre = (low + high) / 2
    critic = HandCritic()
    td3_target(
        torch.zeros(20000),
        torch.zeros(20000, dtype=torch.bool),
        torch.zeros(20000, ACT_DIM),
        gamma=0.99,
        target_actor=ConstantActor(centre.numpy()),
        target_critic=critic,
        policy_noise=0.1,
        noise_clip=10.0,  # never reached
        action_low=low,
        action_high=high,
        generator=torch.Generator().manual_seed(1),
    )
    std = (critic.seen_actions[0] - centre).std(0)
    torch.testing.assert_close(std, 0.1 * (high - low) / 2, rtol=0.03, atol=0.0)


# --- losses, eq. (9) and the policy gradient ------------------------------------------


CRITIC_LOSS_CASES = [
    # q1, q2, y, loss
    ([1.0, 2.0], [0.0, 4.0], [1.0, 1.0], (0 + 1) / 2 + (1 + 9) / 2),  # 5.5
    ([3.0], [3.0], [3.0], 0.0),
    ([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [-1.0, 2.0, 0.0], (1 + 4 + 0) / 3 + (4 + 1 + 1) / 3),
]


@pytest.mark.parametrize(("q1", "q2", "y", "expected"), CRITIC_LOSS_CASES)
def test_critic_loss_hand_values(
    q1: list[float], q2: list[float], y: list[float], expected: float
) -> None:
    loss = critic_loss(torch.tensor(q1), torch.tensor(q2), torch.tensor(y))
    assert loss.item() == pytest.approx(expected)


def test_actor_loss_hand_value_and_gradient() -> None:
    # pi(s) = w s, Q1(s, a) = s a  =>  loss = -w mean(s^2), d loss / d w = -mean(s^2).
    obs = torch.tensor([[1.0], [2.0]])
    actor = ScaledActor(2.0)
    loss = actor_loss(HandCritic(), actor, obs)  # type: ignore[arg-type]
    assert loss.item() == pytest.approx(-2.0 * 2.5)
    loss.backward()
    assert actor.w.grad is not None
    assert actor.w.grad.item() == pytest.approx(-2.5)


def test_soft_update_polyak_average() -> None:
    target, source = nn.Linear(2, 2), nn.Linear(2, 2)
    nn.init.zeros_(target.weight), nn.init.zeros_(target.bias)
    nn.init.ones_(source.weight), nn.init.ones_(source.bias)
    soft_update(target, source, 0.25)
    assert torch.allclose(flat_params(target), torch.full((6,), 0.25))
    soft_update(target, source, 0.25)
    assert torch.allclose(flat_params(target), torch.full((6,), 0.25 + 0.75 * 0.25))


# --- TD3Learner -----------------------------------------------------------------------


@pytest.mark.parametrize("policy_delay", [1, 2, 3])
def test_actor_and_targets_update_every_policy_delay_calls(policy_delay: int) -> None:
    learner = td3_learner(dataclasses.replace(SMALL, policy_delay=policy_delay))
    batch = td3_batch()
    for call in range(1, 8):
        actor, target_critic = flat_params(learner.actor), flat_params(learner.target_critic)
        metrics = learner.update(batch)
        delayed = call % policy_delay == 0
        assert ("losses/actor" in metrics) is delayed
        assert (not torch.equal(actor, flat_params(learner.actor))) is delayed
        assert (not torch.equal(target_critic, flat_params(learner.target_critic))) is delayed
        assert {"losses/critic", "values/q1_mean"} <= metrics.keys()
    assert learner.num_updates == 7
    assert learner.num_actor_updates == 7 // policy_delay


def test_frozen_actor_updates_keep_actor_but_move_targets() -> None:
    learner = td3_learner(dataclasses.replace(SMALL, policy_delay=2, frozen_actor_updates=4))
    initial_actor = flat_params(learner.actor)
    batch = td3_batch()
    actor_calls, target_calls = [], []
    for call in range(1, 9):
        target_critic = flat_params(learner.target_critic)
        if "losses/actor" in learner.update(batch):
            actor_calls.append(call)
        if not torch.equal(target_critic, flat_params(learner.target_critic)):
            target_calls.append(call)
        if call <= 5:
            assert torch.equal(flat_params(learner.actor), initial_actor)
    assert actor_calls == [6, 8]
    assert target_calls == [2, 4, 6, 8]
    assert not torch.equal(flat_params(learner.actor), initial_actor)


def test_truncated_bootstraps_and_terminated_does_not() -> None:
    batch = td3_batch()
    flipped_truncated = dict(batch, truncated=~batch["truncated"])
    flipped_terminated = dict(batch, terminated=~batch["terminated"])
    reference = td3_learner().update(batch)["losses/critic"]
    assert td3_learner().update(flipped_truncated)["losses/critic"] == reference
    assert td3_learner().update(flipped_terminated)["losses/critic"] != reference


def test_critic_sees_stored_action_clipped_into_bounds() -> None:
    batch = td3_batch()
    clipped = dict(
        batch, action=torch.clamp(batch["action"], torch.tensor(LOW), torch.tensor(HIGH))
    )
    assert not torch.equal(clipped["action"], batch["action"])  # the batch does leave the box
    a, b = td3_learner(), td3_learner()
    assert a.update(batch) == b.update(clipped)
    assert torch.equal(flat_params(a.critic), flat_params(b.critic))


def test_checkpoint_resume_is_bit_identical() -> None:
    config = dataclasses.replace(SMALL, policy_delay=2)
    batches = [td3_batch(seed=i) for i in range(15)]
    learner = td3_learner(config, seed=0)
    for batch in batches[:10]:
        learner.update(batch)
    buffer = io.BytesIO()
    torch.save(learner.state_dict(), buffer)
    expected_metrics = [learner.update(batch) for batch in batches[10:]]

    buffer.seek(0)
    resumed = td3_learner(config, seed=123)  # different init: everything must come from the file
    resumed.load_state_dict(torch.load(buffer, weights_only=True))
    metrics = [resumed.update(batch) for batch in batches[10:]]

    assert metrics == expected_metrics
    assert resumed.num_updates == learner.num_updates == 15
    assert resumed.num_actor_updates == learner.num_actor_updates == 7
    for name in ("actor", "critic", "target_actor", "target_critic"):
        a, b = getattr(learner, name).state_dict(), getattr(resumed, name).state_dict()
        assert all(torch.equal(a[k], b[k]) for k in a), name
    for name in ("actor_optimizer", "critic_optimizer"):
        a, b = getattr(learner, name).state_dict(), getattr(resumed, name).state_dict()
        for k, state in a["state"].items():
            assert all(
                torch.equal(torch.as_tensor(v), torch.as_tensor(b["state"][k][n]))
                for n, v in state.items()
            ), name


def test_critic_loss_decreases_on_a_fixed_batch() -> None:
    learner = td3_learner(TD3Config(hidden_sizes=(64, 64), critic_lr=3e-3))
    batch = td3_batch(n=64)
    losses = [learner.update(batch)["losses/critic"] for _ in range(50)]
    assert np.mean(losses[-5:]) < 0.5 * np.mean(losses[:5])


def test_same_seed_same_learner_and_global_rng_untouched() -> None:
    torch.manual_seed(7)
    before = torch.random.get_rng_state()
    a, b = td3_learner(seed=3), td3_learner(seed=3)
    assert torch.equal(torch.random.get_rng_state(), before)
    assert torch.equal(flat_params(a.critic), flat_params(b.critic))
    assert not torch.equal(flat_params(a.critic), flat_params(td3_learner(seed=4).critic))
