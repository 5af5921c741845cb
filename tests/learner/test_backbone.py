"""The hard-coded policy as backbone (learner/backbone and the backbone behaviour): action
composition (eq. 10), the observed backbone, the teacher target (eq. 11) and the burn-in."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
import torch
from torch import nn

from actors.behaviours.backbone import BackboneBehaviour, compose_action
from actors.policy_net import ActingNet
from learner.backbone.learning import ibrl_target, teacher_target
from learner.backbone.networks import zero_output_
from learner.td3.networks import Actor, acting_copy
from tests.learner.helpers import FixedRows

# --- the behaviour: eq. (10) ----------------------------------------------------------


def test_backbone_action_composition_clips_the_correction_then_the_action():
    mu = np.array([[1.8], [-1.0], [0.0]], np.float32)
    correction = np.array([[1.0], [-0.3], [-5.0]], np.float32)
    action = compose_action(mu, correction, limit=0.5, low=np.array([-2.0]), high=np.array([2.0]))
    # 1.8 + 0.5 = 2.3 -> 2.0;  -1.0 - 0.3 = -1.3;  0.0 + clip(-5) = -0.5
    np.testing.assert_allclose(action, [[2.0], [-1.3], [-0.5]], rtol=1e-6)


def _pendulum_backbone(correction: ActingNet, backbone, **kwargs) -> BackboneBehaviour:
    """A backbone behaviour over Pendulum's torque box [−2, 2], exploration σ = 0.2."""
    low, high = np.array([-2.0]), np.array([2.0])
    return BackboneBehaviour(
        correction, backbone, std=0.2, prefill_std=0.3, low=low, high=high, **kwargs
    )


def test_correction_network_starts_at_zero_so_the_agent_starts_as_the_backbone():
    correction = zero_output_(Actor(3, 1, np.array([-0.5]), np.array([0.5]), (8,)))
    backbone = lambda obs: np.full((len(obs), 1), 1.7, np.float32)  # noqa: E731
    behaviour = _pendulum_backbone(acting_copy(correction), backbone, limit=0.5)
    obs = np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32)
    np.testing.assert_allclose(behaviour.greedy(obs), np.full((5, 1), 1.7))
    env_action, columns = behaviour.act(obs, np.random.default_rng(1), warmup=False)
    # Replay stores μ(s) and the (unclipped) correction separately; noise is on the correction.
    np.testing.assert_allclose(columns["backbone_action"], np.full((5, 1), 1.7))
    expected = np.clip(1.7 + np.clip(columns["action"], -0.5, 0.5), -2.0, 2.0)
    np.testing.assert_allclose(env_action, expected, rtol=1e-6)
    assert np.abs(columns["action"]).max() > 0.0


def _Recorder() -> FixedRows:
    """A correction network that records its input and outputs zero."""
    return FixedRows([[0.0]])


def test_observed_backbone_is_an_input_of_the_correction_and_recorded_at_s_prime():
    correction = _Recorder()
    backbone = lambda obs: np.where(obs[:, 2:] >= 0, 2.0, -2.0).astype(np.float32)  # noqa: E731
    behaviour = _pendulum_backbone(correction, backbone, limit=4.0, observe_backbone=True)
    obs = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, -3.0]], np.float32)
    behaviour.greedy(obs)
    # [s, μ(s) / 2]: μ = +2 and −2 -> +1 and −1.
    np.testing.assert_array_equal(correction.seen, [[1.0, 0.0, 0.5, 1.0], [0.0, 1.0, -3.0, -1.0]])
    assert "next_backbone_action" in behaviour.columns()
    next_obs = np.array([[1.0, 0.0, -0.1], [0.0, 1.0, 0.2]], np.float32)
    np.testing.assert_allclose(
        behaviour.next_columns(next_obs)["next_backbone_action"], [[-2.0], [2.0]]
    )


def _counting_backbone(ticked: list[int]) -> Callable[[np.ndarray], np.ndarray]:
    """μ(s) = ±2 by the sign of s[2]; each call's batch size goes to `ticked`."""

    def backbone(obs: np.ndarray) -> np.ndarray:
        ticked.append(len(obs))
        return np.where(obs[:, 2:] >= 0, 2.0, -2.0).astype(np.float32)

    return backbone


def test_observed_backbone_ticks_mu_once_per_state():
    ticked: list[int] = []
    backbone = _counting_backbone(ticked)
    behaviour = _pendulum_backbone(_Recorder(), backbone, limit=4.0, observe_backbone=True)
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(4, 3)).astype(np.float32)
    behaviour.act(obs, rng, warmup=False)
    next_obs = rng.normal(size=(4, 3)).astype(np.float32)
    mu_next = behaviour.next_columns(next_obs)["next_backbone_action"]
    restarted = next_obs.copy()
    restarted[1] = [0.0, 1.0, -5.0]  # env 1's episode ended: its next s is a reset state
    _, columns = behaviour.act(restarted, rng, warmup=False)
    # 4 rows, 4 rows of s', then only the restarted row: μ(s') is reused for the others.
    assert ticked == [4, 4, 1]
    np.testing.assert_array_equal(columns["backbone_action"][[0, 2, 3]], mu_next[[0, 2, 3]])
    np.testing.assert_array_equal(columns["backbone_action"][1], [-2.0])


def test_observed_backbone_reuses_each_environments_mu_when_they_act_apart():
    """Environments at their own pace come in varying subsets (`envs`): μ(s') is kept per
    environment, so a row is ticked again only when its environment's s is new."""
    ticked: list[int] = []
    backbone = _counting_backbone(ticked)
    behaviour = _pendulum_backbone(_Recorder(), backbone, limit=4.0, observe_backbone=True)
    rng = np.random.default_rng(0)
    s = rng.normal(size=(3, 3)).astype(np.float32)
    behaviour.act(s, rng, warmup=False)  # all three environments
    nxt = rng.normal(size=(3, 3)).astype(np.float32)
    behaviour.next_columns(nxt[[2]], envs=np.array([2]))  # only env 2 finished its step
    behaviour.next_columns(nxt[[0]], envs=np.array([0]))  # then env 0
    _, columns = behaviour.act(nxt[[0, 2]], rng, warmup=False, envs=np.array([0, 2]))
    assert ticked == [3, 1, 1]  # the last act ticks nothing: both s were seen as s'
    np.testing.assert_array_equal(columns["backbone_action"], backbone(nxt[[0, 2]]))


# --- the learner: eq. (11), the observed backbone, the burn-in ------------------------


def _batch(rows: int) -> dict[str, torch.Tensor]:
    """A backbone batch of Pendulum's shapes (3-d s, 1-d a): μ(s) = 2, μ(s') = −2."""
    return {
        "obs": torch.zeros(rows, 3),
        "action": torch.zeros(rows, 1),
        "backbone_action": torch.full((rows, 1), 2.0),
        "next_backbone_action": torch.full((rows, 1), -2.0),
        "reward": torch.ones(rows),
        "terminated": torch.zeros(rows, dtype=torch.bool),
        "next_obs": torch.zeros(rows, 3),
    }


def test_observing_learner_appends_mu_to_obs_and_next_obs():
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    learner = ObservingBackboneLearner(
        3, np.array([4.0], np.float32), np.array([2.0]), config=TD3Config(hidden_sizes=(8,)), seed=0
    )
    assert learner.actor.net[0].in_features == 4  # s (3) + μ(s) (1)
    batch = _batch(5)
    with pytest.raises(ValueError, match="next_backbone_action"):
        learner.update({k: v for k, v in batch.items() if k != "next_backbone_action"})
    metrics = learner.update(batch)
    assert math.isfinite(metrics["losses/critic"])


def test_the_observing_learner_standardizes_s_and_not_mu_and_its_behaviour_fits_its_weights():
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.builder import make_actor_network
    from learner.td3.config import TD3Config
    from learner.td3.networks import TwinCritic

    config = TD3Config(hidden_sizes=(8,), standardize_observations=True)
    bound = np.array([4.0], np.float32)
    learner = ObservingBackboneLearner(3, bound, np.array([2.0]), config=config, seed=0)
    batch = _batch(6)
    batch["obs"] = torch.arange(18.0).reshape(6, 3) * 4  # μ(s) / scale = 1 in every row
    learner.update(batch)
    standardize = learner.actor.net[0]
    torch.testing.assert_close(standardize.shift, batch["obs"].mean(dim=0))
    assert learner.actor.net[1].in_features == 4  # s (3) standardized, then μ(s) as it is
    behaviour = make_actor_network(3, 1, -bound, bound, config, extra_inputs=1)
    behaviour.load_state_dict(learner.actor.state_dict())  # the same names and shapes
    critic = TwinCritic(4, 1, (8,), standardized=3)
    critic.load_state_dict(learner.critic.state_dict())


def test_observe_backbone_refuses_a_teacher():
    from learner.backbone.config import BackboneConfig

    with pytest.raises(ValueError, match="observe_backbone"):
        BackboneConfig(observe_backbone=True, teacher="runs/teacher")


def test_eq11_teacher_target():
    y = teacher_target(
        torch.tensor([1.0, -1.0]),
        torch.tensor([False, True]),
        gamma=0.9,
        teacher_next_value=torch.tensor([-10.0, -20.0]),
        next_correction_value=torch.tensor([2.0, 3.0]),
    )
    # 1 + 0.9·(−10 + 2) = −6.2; the terminal row keeps only r.
    torch.testing.assert_close(y, torch.tensor([-6.2, -1.0]))


def test_ibrl_target_bootstraps_from_the_better_of_pi_and_the_tree():
    y = ibrl_target(
        torch.tensor([1.0, 1.0, -1.0]),
        torch.tensor([False, False, True]),
        gamma=0.9,
        next_policy_value=torch.tensor([-10.0, 4.0, 5.0]),
        next_tree_value=torch.tensor([-2.0, 3.0, 9.0]),
    )
    # 1 + 0.9·max(−10, −2) = −0.8; 1 + 0.9·max(4, 3) = 4.6; the terminal row keeps only r.
    torch.testing.assert_close(y, torch.tensor([-0.8, 4.6, -1.0]))


def test_the_learners_tree_proposal_is_the_zero_correction_valued_by_the_target_critic():
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    def make(tree_in_target: bool) -> ObservingBackboneLearner:
        return ObservingBackboneLearner(
            2,
            np.array([1.0], np.float32),
            np.array([1.0]),
            config=TD3Config(hidden_sizes=(8,), policy_noise=0.0),
            seed=0,
            tree_in_target=tree_in_target,
        )

    plain, ibrl = make(False), make(True)
    batch = {
        "reward": torch.zeros(4),
        "terminated": torch.zeros(4, dtype=torch.bool),
        "next_obs": torch.randn(4, 3),  # s' and μ(s'), as `update` forms it
    }
    policy = plain._critic_target(batch)
    tree = 0.99 * torch.min(*ibrl.target_critic(batch["next_obs"], torch.zeros(4, 1)))
    torch.testing.assert_close(ibrl._critic_target(batch), torch.maximum(policy, tree.detach()))


def test_backbone_critic_burn_in_is_extra_updates_at_learning_starts_with_the_actor_frozen():
    from graft.config import load_preset
    from graft.registry import make_builder

    config = load_preset(
        "pendulum-backbone",
        env_steps=3000,
        learning_starts=2000,
        **{"td3.burn_in_updates": 50, "td3.frozen_actor_updates": 50},
        **{"td3.hidden_sizes": [32, 32]},
    )
    builder = make_builder(config)
    (phase,) = builder.phases()
    # 1,000 online updates (3,000 - 2,000 steps at 1 per step) plus the 50 of the burn-in,
    # which the rate limiter lets the learner draw at min_size: 50 batches of 256 items.
    assert phase.updates == 1050
    assert phase.min_size == 2000
    assert phase.sample_credit == 50 * 256
    learner = builder.make_learner()
    before = [p.clone() for p in learner.actor.parameters()]
    batch = _batch(256)
    for _ in range(50):
        learner.update(batch)
    assert learner.num_actor_updates == 0  # the correction is still exactly zero
    assert all(torch.equal(a, b) for a, b in zip(before, learner.actor.parameters(), strict=True))
    learner.update(batch)
    learner.update(batch)
    assert learner.num_actor_updates == 1


# --- conservative updates near the backbone -------------------------------------------


class _FixedCorrection(nn.Module):
    """π(s) = the given corrections, whatever s (a parameter, so it has a gradient)."""

    def __init__(self, corrections: list[list[float]]) -> None:
        super().__init__()
        self.c = nn.Parameter(torch.tensor(corrections))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.c


class _LinearQ(nn.Module):
    """Q1(s, c) = w · c + b per row (only its first head is used)."""

    def __init__(self, w: float, b: float) -> None:
        super().__init__()
        self.w, self.b = w, b

    def q1(self, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.w * action.sum(-1) + self.b


# Hand-computed: c = [[0.5], [-1.0]], L = 2.
# Q = 4c + 10 = [12, 6]: mean 9, mean|Q| 9 -> -1; penalty mean((c/L)²) = (0.0625 + 0.25)/2.
CONSERVATIVE_CASES = [
    (4.0, 10.0, 0.0, -1.0),
    (4.0, 10.0, 2.0, -1.0 + 2.0 * 0.15625),
    # Q = -4c - 10 = [-12, -6]: mean -9, mean|Q| 9 -> +1.
    (-4.0, -10.0, 1.0, 1.0 + 0.15625),
]


@pytest.mark.parametrize("w, b, penalty, expected", CONSERVATIVE_CASES)
def test_conservative_actor_loss_matches_hand_computed_values(w, b, penalty, expected):
    from learner.backbone.learning import conservative_actor_loss

    loss = conservative_actor_loss(
        _LinearQ(w, b),
        _FixedCorrection([[0.5], [-1.0]]),
        torch.zeros(2, 3),
        bound=torch.tensor([2.0]),
        penalty=penalty,
    )
    assert loss.item() == pytest.approx(expected, rel=1e-6)


def test_the_penalty_pulls_a_correction_the_critic_does_not_value_back_to_zero():
    from learner.backbone.learning import conservative_actor_loss

    actor = _FixedCorrection([[0.5], [-1.0]])
    flat = _LinearQ(0.0, 10.0)  # the critic sees no gain in any correction
    conservative_actor_loss(
        flat, actor, torch.zeros(2, 3), bound=torch.tensor([2.0]), penalty=1.0
    ).backward()
    # d/dc of mean over 2 rows of (c/2)² = 2c / (4 · 2) = c / 4: descent moves c towards 0.
    np.testing.assert_allclose(actor.c.grad.numpy(), [[0.125], [-0.25]], rtol=1e-6)


def test_correction_penalty_needs_the_residual_learner():
    from learner.backbone.config import BackboneConfig

    with pytest.raises(ValueError, match="correction_penalty=0.5 needs observe_backbone"):
        BackboneConfig(correction_penalty=0.5)
    with pytest.raises(ValueError, match="correction_penalty=-1.0 must be >= 0"):
        BackboneConfig(correction_penalty=-1.0, observe_backbone=True)


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"switch_margin": 0.0}, "switch_margin=0.0 needs observe_backbone=True"),
        ({"switch_margin": -0.1, "observe_backbone": True}, "switch_margin=-0.1 must be >= 0"),
        ({"tree_in_target": True}, "tree_in_target=True needs observe_backbone=True"),
        ({"tree_in_acting": True}, "tree_in_acting=True needs observe_backbone=True"),
    ],
)
def test_switching_settings_are_refused_by_name(fields, message):
    from learner.backbone.config import BackboneConfig

    with pytest.raises(ValueError, match=message):
        BackboneConfig(**fields)


def test_the_switching_learner_publishes_its_critic_and_checkpoints_the_tree_only_flag():
    from actors.behaviours.switching import TREE_ONLY, split_weights
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    def make(seed: int) -> ObservingBackboneLearner:
        return ObservingBackboneLearner(
            3,
            np.array([4.0], np.float32),
            np.array([2.0]),
            config=TD3Config(hidden_sizes=(8,), frozen_actor_updates=2),
            seed=seed,
            publish_critic=True,
        )

    batch = _batch(5)
    learner = make(0)
    # An untrained π (here: frozen for 2 updates, then TD3's delay of 2) is not published
    # as the greedy policy: the tree alone acts until π's first gradient step.
    for _ in range(3):
        assert split_weights(learner.policy_state())[2] is True
        learner.update(batch)
    learner.update(batch)
    assert learner.num_actor_updates == 1
    policy, critic, tree_only = split_weights(learner.policy_state())
    assert set(policy) == set(learner.actor.state_dict()) and not tree_only
    assert set(critic) == set(learner.critic.state_dict())
    assert learner.tree_state()[TREE_ONLY].item() == 1.0
    learner.keep_tree()
    again = make(1)
    again.load_state_dict(learner.state_dict())
    assert split_weights(again.policy_state())[2] is True


def test_the_correction_ramp_widens_pis_published_range_and_the_critic_keeps_the_whole_box():
    from actors.policy_net import PolicyNet
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    learner = ObservingBackboneLearner(
        3,
        np.array([4.0], np.float32),
        np.array([2.0]),
        config=TD3Config(hidden_sizes=(8,), policy_delay=1, actor_lr=0.1),
        seed=0,
        ramp_actor_updates=4,
    )
    batch = {
        "obs": torch.zeros(8, 3),
        "action": torch.full((8, 1), 3.5),  # acted with the whole range: stored as it was
        "backbone_action": torch.zeros(8, 1),
        "next_backbone_action": torch.zeros(8, 1),
        "reward": torch.ones(8),
        "terminated": torch.zeros(8, dtype=torch.bool),
        "next_obs": torch.zeros(8, 3),
    }
    ranges = []
    for _ in range(6):
        learner.update(batch)
        ranges.append(learner.actor.action_high.item())
        assert learner.target_actor.action_high.item() == ranges[-1]
    assert ranges == pytest.approx([1.0, 2.0, 3.0, 4.0, 4.0, 4.0])  # ±L·(step / 4), then ±L
    assert learner.action_box[1].item() == 4.0  # the critic values every action taken
    # The actors' copy squashes into the published range.
    policy = learner.policy_state()
    assert policy["action_high"].item() == 4.0
    net = PolicyNet({k: v.numpy() for k, v in policy.items() if not k.startswith("critic.")})
    assert np.all(np.abs(net(np.zeros((2, 4), np.float32))) <= 4.0)


def test_the_correction_ramp_is_a_share_of_the_actor_steps_and_needs_the_residual_learner():
    from learner.backbone.config import BackboneConfig

    with pytest.raises(ValueError, match=r"correction_ramp=1.5 must be in \[0, 1\]"):
        BackboneConfig(correction_ramp=1.5, observe_backbone=True)
    with pytest.raises(ValueError, match="correction_ramp=0.5 needs observe_backbone"):
        BackboneConfig(correction_ramp=0.5)


def test_clone_tree_fits_a_standalone_pi_to_the_tree_while_the_actor_is_frozen():
    from learner.backbone.config import BackboneConfig
    from learner.backbone.learning import ObservingBackboneLearner
    from learner.td3.config import TD3Config

    def make(clone: bool) -> ObservingBackboneLearner:
        return ObservingBackboneLearner(
            3,
            np.array([2.0], np.float32),
            np.array([2.0]),
            config=TD3Config(hidden_sizes=(32,), frozen_actor_updates=600, actor_lr=3e-3),
            seed=0,
            centre=np.zeros(1, np.float32),
            clone_tree=clone,
        )

    rng = np.random.default_rng(0)
    obs = torch.as_tensor(rng.uniform(-1, 1, (256, 3)), dtype=torch.float32)
    batch = dict(_batch(256), obs=obs, backbone_action=1.5 * torch.sign(obs[:, :1]))

    def error(learner: ObservingBackboneLearner) -> float:
        x = learner._observe(batch)["obs"]
        with torch.no_grad():
            return float(((learner.actor(x) - batch["backbone_action"]) ** 2).mean())

    cloned, plain = make(True), make(False)
    before = error(cloned)
    assert before == error(plain) > 1.0  # one initialisation: π is far from the tree
    for _ in range(600):
        metrics = cloned.update(batch)
        plain.update(batch)
    assert error(cloned) < 0.05 * before and "losses/clone" in metrics
    assert error(plain) == before  # frozen without cloning: π has not moved
    assert cloned.num_actor_updates == 0  # cloning is not TD3's actor step
    with pytest.raises(ValueError, match="standalone"):
        ObservingBackboneLearner(
            3,
            np.array([2.0], np.float32),
            np.array([2.0]),
            config=TD3Config(),
            seed=0,
            clone_tree=True,
        )
    with pytest.raises(ValueError, match="clone_tree=True needs residual=False"):
        BackboneConfig(observe_backbone=True, clone_tree=True)


@pytest.mark.parametrize("standardize", [False, True])
def test_a_teacher_with_layer_norm_critics_loads_as_it_trained(tmp_path, standardize):
    """A TD3 teacher with `td3.critic_layer_norm`, widths of its own and standardized
    observations or not loads from its checkpoint alone (no config.yaml beside it) as the
    networks it trained."""
    import dataclasses

    from learner.backbone.networks import load_teacher
    from learner.checkpoint import save_checkpoint
    from tests.learner.helpers import ACT_DIM, HIGH, LOW, OBS_DIM, SMALL, td3_batch, td3_learner

    config = dataclasses.replace(
        SMALL, critic_layer_norm=True, hidden_sizes=(12, 10), standardize_observations=standardize
    )
    teacher = td3_learner(config)
    batch = td3_batch(seed=3)
    batch["obs"] = 10 * batch["obs"] + 4
    teacher.update(batch)  # fits the standardizers, when there are any
    save_checkpoint(tmp_path / "checkpoints", {"algorithm": teacher.state_dict()}, updates=1)
    actor, critic = load_teacher(str(tmp_path), OBS_DIM, ACT_DIM, LOW, HIGH)
    obs, act = torch.randn(5, OBS_DIM), torch.randn(5, ACT_DIM)
    torch.testing.assert_close(critic(obs, act), teacher.critic(obs, act))
    torch.testing.assert_close(actor(obs), teacher.actor(obs))
    assert any(isinstance(m, nn.LayerNorm) for m in critic.modules())
