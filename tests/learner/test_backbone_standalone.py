"""Backbone TD3 with a standalone actor (``backbone.residual: false``, IBRL's form): π acts
the action itself around the box's centre, and the tree is only a proposal, μ(s) − centre
as π's output, in the prefill, in acting, in switching and in the TD target."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces

from actors.behaviours.backbone import BackboneBehaviour
from learner.agent import Budget
from learner.backbone.builder import BackboneBuilder
from learner.backbone.config import BackboneConfig
from learner.backbone.learning import ObservingBackboneLearner
from learner.td3.builder import TD3Builder
from learner.td3.config import TD3Config
from tests.actors.test_switching import LinearTwin
from tests.learner.helpers import FixedRows

LOW, HIGH = np.array([-1.0, 0.0], np.float32), np.array([3.0, 1.0], np.float32)
CENTRE = np.array([1.0, 0.5], np.float32)  # half-widths 2 and 0.5


def _tree(obs: np.ndarray) -> np.ndarray:
    """μ(s) = (0.5, 0.9) everywhere: the standalone tree's proposal is (−0.5, +0.4)."""
    return np.tile(np.array([[0.5, 0.9]], np.float32), (len(obs), 1))


def _standalone(pi: list[float], **kwargs) -> BackboneBehaviour:
    return BackboneBehaviour(
        FixedRows([pi]),
        _tree,
        limit=2.0,
        std=0.1,
        prefill_std=0.1,
        low=LOW,
        high=HIGH,
        observe_backbone=True,
        centre=CENTRE,
        **kwargs,
    )


# --- the config ---------------------------------------------------------------------


@pytest.mark.parametrize(
    "fields, message",
    [
        ({}, "residual=False needs observe_backbone=True"),
        (
            {"observe_backbone": True, "correction_penalty": 0.5},
            "correction_penalty=0.5 needs residual=True",
        ),
        (
            {"observe_backbone": True, "correction_ramp": 0.2},
            "correction_ramp=0.2 needs residual=True",
        ),
    ],
)
def test_a_standalone_actor_refuses_the_settings_it_cannot_take_by_name(fields, message):
    with pytest.raises(ValueError, match=message):
        BackboneConfig(residual=False, **fields)


def test_a_standalone_actor_takes_the_recipes_other_settings():
    config = BackboneConfig(
        residual=False,
        observe_backbone=True,
        correction_limit=4.0,  # not used: π's range is the box
        switch_margin=0.0,
        tree_in_acting=True,
        tree_in_target=True,
    )
    assert not config.residual and BackboneConfig().residual  # the residual by default


# --- the behaviour ------------------------------------------------------------------


def test_the_standalone_action_is_pis_output_around_the_centre_clipped_to_the_box():
    obs = np.zeros((2, 3), np.float32)
    # centre + π = (1 + 1.5, 0.5 + 0.2): the tree's μ(s) plays no part in it.
    np.testing.assert_allclose(_standalone([1.5, 0.2]).greedy(obs), [[2.5, 0.7]] * 2)
    # (1 + 3.0, 0.5 − 0.7) leaves the box on both sides: clipped to (3, 0).
    np.testing.assert_allclose(_standalone([3.0, -0.7]).greedy(obs), [[3.0, 0.0]] * 2)


def test_the_standalone_prefill_acts_the_tree_and_stores_mu_minus_centre_plus_noise():
    behaviour = _standalone([1.5, 0.2])
    obs = np.zeros((500, 3), np.float32)
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=True)
    np.testing.assert_allclose(action.mean(axis=0), [0.5, 0.9], atol=0.02)  # μ(s) + ε
    # Stored unclipped; the environment applied centre + c clipped to the box.
    np.testing.assert_allclose(np.clip(CENTRE + columns["action"], LOW, HIGH), action, atol=1e-6)
    np.testing.assert_allclose(columns["backbone_action"], _tree(obs))
    # The stored sample is μ(s) − centre + ε: the noise is drawn around the tree's proposal.
    noise = columns["action"] - (_tree(obs) - CENTRE)
    assert 0.08 < float(noise.std()) < 0.12 and abs(float(noise.mean())) < 0.02


def test_a_uniform_prefill_spans_the_box_and_stores_the_correction_that_composes_it():
    behaviour = _standalone([1.5, 0.2], prefill_uniform=1.0)
    obs = np.zeros((4000, 3), np.float32)
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=True)
    assert (action >= LOW).all() and (action <= HIGH).all()
    # Uniform on [−1, 3] x [0, 1]: means 1 and 0.5, stds 4/√12 and 1/√12; the tree's
    # (0.5, 0.9) and π's output play no part in it.
    np.testing.assert_allclose(action.mean(axis=0), CENTRE, atol=0.05)
    np.testing.assert_allclose(action.std(axis=0), (HIGH - LOW) / np.sqrt(12), rtol=0.05)
    np.testing.assert_allclose(CENTRE + columns["action"], action, atol=1e-6)
    np.testing.assert_allclose(columns["backbone_action"], _tree(obs))
    np.testing.assert_allclose(columns["log_prob"], -np.log(4.0 * 1.0))  # 1 / the box's area
    acting, _ = behaviour.act(obs[:500], np.random.default_rng(0), warmup=False)
    np.testing.assert_allclose(acting.mean(axis=0), [2.5, 0.7], atol=0.02)  # after: π's


def test_a_mixed_prefill_acts_either_at_even_odds_with_the_mixtures_log_likelihood():
    behaviour = _standalone([1.5, 0.2], prefill_uniform=0.5)
    obs = np.zeros((4000, 3), np.float32)
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=True)
    near_tree = np.all(np.abs(action - [0.5, 0.9]) < 0.5, axis=1)  # μ(s) + ε, σ = 0.1
    # Half the steps are the tree's; of the uniform half, 1/4 x 0.6 fall near it too.
    assert 0.53 < near_tree.mean() < 0.62  # 0.5 + 0.5 x 0.15 = 0.575
    correction = columns["action"]
    tree_density = np.exp(
        -0.5 * (((correction - (_tree(obs) - CENTRE)) / 0.1) ** 2).sum(axis=1)
    ) / (2 * np.pi * 0.1**2)
    inside = np.all((CENTRE + correction >= LOW) & (CENTRE + correction <= HIGH), axis=1)
    expected = np.log(0.5 * tree_density + 0.5 * inside / 4.0)
    np.testing.assert_allclose(columns["log_prob"], expected, rtol=1e-4, atol=1e-5)


def test_a_prefill_that_is_none_of_tree_mixed_uniform_is_refused_by_name():
    with pytest.raises(ValueError, match="prefill='random' must be one of tree, mixed, uniform"):
        BackboneConfig(prefill="random")


@pytest.mark.parametrize(
    "a1, a2, expected",
    [
        # Q(c) = a·c on the first dimension: π's 1.5 against the tree's −0.5.
        (1.0, 1.0, [2.5, 0.7]),  # 1.5 > −0.5: π's action
        (-1.0, -1.0, [0.5, 0.9]),  # −1.5 < +0.5: the tree's μ(s) (a zero correction: 1.0, 0.5)
    ],
)
def test_standalone_switching_and_acting_choose_between_pi_and_mu(a1, a2, expected):
    obs = np.zeros((300, 3), np.float32)
    greedy = _standalone([1.5, 0.2], critic=LinearTwin(a1, a2), switch_margin=0.0)
    np.testing.assert_allclose(greedy.greedy(obs[:2]), [expected] * 2, atol=1e-6)
    acting = _standalone([1.5, 0.2], critic=LinearTwin(a1, a2), propose_tree=True)
    action, _ = acting.act(obs, np.random.default_rng(0), warmup=False)
    np.testing.assert_allclose(action.mean(axis=0), expected, atol=0.02)


def test_the_standalone_tree_proposal_is_mu_itself_when_the_tree_is_kept():
    behaviour = _standalone([1.5, 0.2], critic=LinearTwin(-1.0, -1.0), switch_margin=0.0)
    behaviour.load({"rows": np.array([[1.5, 0.2]]), "critic.a": np.array([-1.0, -1.0])})
    np.testing.assert_allclose(behaviour.greedy(np.zeros((1, 3), np.float32)), [[0.5, 0.9]])
    assert behaviour.stats() == {"switch/policy_share": 0.0}


# --- the learner and the builder ----------------------------------------------------


def _learner(centre, *, tree_in_target: bool = True) -> ObservingBackboneLearner:
    return ObservingBackboneLearner(
        2,
        ((HIGH - LOW) / 2).astype(np.float32),
        HIGH,
        config=TD3Config(hidden_sizes=(8,), policy_noise=0.0),
        seed=0,
        tree_in_target=tree_in_target,
        centre=centre,
    )


def test_the_standalone_ibrl_target_values_mu_of_s_prime_minus_the_centre():
    standalone, residual = _learner(CENTRE), _learner(None)
    plain = _learner(CENTRE, tree_in_target=False)  # same seed, same networks
    mu = torch.tensor([[0.5, 0.9], [3.0, 0.0], [-1.0, 1.0], [2.0, 0.25]])
    batch = {
        "reward": torch.zeros(4),
        "terminated": torch.zeros(4, dtype=torch.bool),
        "next_obs": torch.randn(4, 4, generator=torch.Generator().manual_seed(0)),
        "next_backbone_action": mu,
    }
    policy = plain._critic_target(batch)  # min(Q1', Q2')(s', π'(s')), discounted
    tree = 0.99 * torch.min(*plain.target_critic(batch["next_obs"], mu - torch.tensor(CENTRE)))
    expected = torch.maximum(policy, tree.detach())
    torch.testing.assert_close(standalone._critic_target(batch), expected)
    # The residual's tree is the zero correction: a different value here.
    assert not torch.allclose(residual._critic_target(batch), expected)


def _pendulum_td3(**config) -> TD3Builder:
    """TD3's builder on Pendulum's spaces (open observation bounds, torque in ±2)."""
    return TD3Builder(
        spaces.Box(-np.inf, np.inf, (3,), np.float32),
        spaces.Box(-2.0, 2.0, (1,), np.float32),
        config=TD3Config(hidden_sizes=(8,), **config),
        budget=Budget(env_steps=100, learning_starts=10, updates_per_env_step=1.0,
                      slack_env_steps=0),
        seed=0,
        method="backbone_td3",
    )  # fmt: skip


def test_the_standalone_builder_spans_the_box_and_keeps_td3s_initialisation():
    td3 = _pendulum_td3()

    def build(residual: bool) -> BackboneBuilder:
        config = BackboneConfig(correction_limit=4.0, observe_backbone=True, residual=residual)
        return BackboneBuilder("actors.trees.pendulum:swing_up", td3, config=config)

    standalone, residual = build(False), build(True)
    learner = standalone.make_learner()
    assert learner.action_box[1].tolist() == [2.0]  # the box, not ±L = ±4
    assert learner.actor.net[-1].weight.abs().sum() > 0  # TD3's initialisation
    assert residual.make_learner().actor.net[-1].weight.abs().sum() == 0  # zero output
    behaviour = standalone.make_behaviour(num_actors=1)
    assert behaviour.centre is not None and behaviour.centre.tolist() == [0.0]
    assert behaviour.limit == 2.0 and residual.make_behaviour(num_actors=1).centre is None


def test_without_tree_input_the_networks_see_s_alone_and_mu_stays_the_proposal():
    td3 = _pendulum_td3(batch_size=4)

    def build(tree_input: bool) -> BackboneBuilder:
        config = BackboneConfig(
            observe_backbone=True,
            residual=False,
            tree_in_target=True,
            tree_in_acting=True,
            tree_input=tree_input,
        )
        return BackboneBuilder("actors.trees.pendulum:swing_up", td3, config=config)

    seeing, blind = build(True), build(False)
    assert seeing.make_learner().actor.net[0].in_features == 4  # [s, μ(s)]
    learner = blind.make_learner()
    assert learner.actor.net[0].in_features == 3 and learner.critic.q1_net[0].in_features == 4
    gen = torch.Generator().manual_seed(0)
    batch = {
        "obs": torch.randn(4, 3, generator=gen),
        "action": torch.rand(4, 1, generator=gen) * 4 - 2,
        "reward": torch.randn(4, generator=gen),
        "next_obs": torch.randn(4, 3, generator=gen),
        "terminated": torch.zeros(4, dtype=torch.bool),
        "backbone_action": torch.full((4, 1), 2.0),
        "next_backbone_action": torch.full((4, 1), 2.0),
    }
    learner.update(batch)  # trains on s alone, the batch's μ columns beside it
    flipped = dict(batch, next_backbone_action=torch.full((4, 1), -2.0))
    # μ(s') is still the tree's proposal in the TD target.
    assert not torch.allclose(learner._critic_target(batch), learner._critic_target(flipped))
    behaviour = blind.make_behaviour(num_actors=1)
    behaviour.load({k: v.numpy() for k, v in learner.policy_state().items()})
    obs = np.array([[1.0, 0.0, 0.5], [1.0, 0.0, -0.5]], np.float32)  # μ flips with θ̇
    action, columns = behaviour.act(obs, np.random.default_rng(0), warmup=False)
    assert action.shape == (2, 1) and columns["backbone_action"].tolist() == [[-2.0], [2.0]]
    assert set(behaviour.next_columns(obs)) == {"next_backbone_action"}


def test_tree_input_false_needs_a_standalone_actor():
    with pytest.raises(ValueError, match="tree_input=False needs a standalone actor"):
        BackboneConfig(observe_backbone=True, tree_input=False)
