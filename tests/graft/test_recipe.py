"""graft's default recipe (graft/recipe.py): a preset that names a hard-coded policy
and no algorithm trains with it, chosen by the action space; the preset's own fields win."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from graft.cli import main
from graft.config import load_preset
from graft.recipe import recipe_description


def _preset(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "task.yaml"
    path.write_text(text)
    return path


PENDULUM = "env_id: Pendulum-v1\nhardcoded_policy: actors.trees.pendulum:swing_up\n"
CARTPOLE = "env_id: CartPole-v1\nhardcoded_policy: cartpole_example.trees:balance\n"


def test_a_tree_with_continuous_actions_gets_the_residual_recipe_scaled_to_its_box(tmp_path):
    config = load_preset(_preset(tmp_path, PENDULUM + "env_steps: 20000\n"))
    assert (config.recipe, config.algorithm) == ("continuous", "backbone_td3")
    assert config.backbone.observe_backbone
    # Written in half-widths of the action box: Pendulum's torque box [-2, 2] doubles them.
    assert config.backbone.correction_limit == 4.0 and config.backbone.prefill_noise == 0.6
    assert config.td3.burn_in_updates > 0 and config.td3.frozen_actor_updates > 0
    assert config.learning_starts == 2000  # a tenth of the 20,000-step budget
    # Greedy switching between π and the tree, and a final selection between them.
    assert config.backbone.switch_margin is not None and config.selection.episodes > 0
    # The tree a proposal in acting and in the TD target (IBRL); standard network sizes.
    assert config.backbone.tree_in_acting and config.backbone.tree_in_target
    assert config.td3.hidden_sizes == (256, 256) and config.td3.batch_size == 256


def test_a_tree_with_discrete_actions_gets_double_dqn_from_its_demonstrations(tmp_path):
    config = load_preset(_preset(tmp_path, CARTPOLE))
    assert (config.recipe, config.algorithm, config.dqn.warmup) == ("discrete", "ddqn", "hardcoded")
    # The margin loss ties Q to the tree in the burn-in only: after it, Q is free to leave.
    assert not config.dqn.margin_after_burn_in and config.dqn.burn_in_updates > 0
    assert config.dqn.switch_margin == 0.0 and config.selection.episodes > 0


@pytest.mark.parametrize("budget, decay", [(50_000, 8_000), (30_000, 4_800), (1_000, 160)])
def test_the_discrete_recipes_exploration_decays_over_a_share_of_the_budget(
    tmp_path, budget, decay
):
    config = load_preset(_preset(tmp_path, CARTPOLE + f"env_steps: {budget}\n"))
    assert config.dqn.epsilon_decay_env_steps == decay
    assert (
        load_preset(_preset(tmp_path, CARTPOLE), env_steps=budget).dqn.epsilon_decay_env_steps
        == decay
    )
    # The preset's own or an override wins.
    own = load_preset(_preset(tmp_path, CARTPOLE + "dqn: {epsilon_decay_env_steps: 7}\n"))
    assert own.dqn.epsilon_decay_env_steps == 7
    set_ = load_preset(_preset(tmp_path, CARTPOLE), **{"dqn.epsilon_decay_env_steps": 9})
    assert set_.dqn.epsilon_decay_env_steps == 9


@pytest.mark.parametrize(
    "text",
    [
        "env_id: Pendulum-v1\n",  # TD3 alone: no tree to fall back to
        PENDULUM + "algorithm: backbone_td3\n",  # μ not observed by the learner
        CARTPOLE + "algorithm: ddqn\n",  # no demonstrations of the tree
    ],
)
def test_a_final_selection_without_a_tree_to_fall_back_to_is_refused(tmp_path, text):
    with pytest.raises(ValueError, match=r"selection.episodes=30 falls back to the tree"):
        load_preset(_preset(tmp_path, text + "selection: {episodes: 30}\n"))


def test_cloning_the_tree_needs_a_frozen_actor_to_clone_it_in(tmp_path):
    clone = {"backbone.clone_tree": True}
    assert load_preset(_preset(tmp_path, PENDULUM), **clone).backbone.clone_tree
    with pytest.raises(ValueError, match=r"clone_tree=true .* td3.frozen_actor_updates > 0"):
        load_preset(_preset(tmp_path, PENDULUM), **clone, **{"td3.frozen_actor_updates": 0})


def test_the_presets_own_fields_and_overrides_win_over_the_recipe(tmp_path):
    preset = _preset(tmp_path, PENDULUM + "td3: {batch_size: 32}\nbackbone: {prefill_noise: 0.1}\n")
    config = load_preset(preset, **{"backbone.correction_limit": 1.5, "learning_starts": 123})
    assert config.td3.batch_size == 32 and config.td3.hidden_sizes == (256, 256)  # both kept
    assert config.backbone.prefill_noise == 0.1 and config.backbone.correction_limit == 1.5
    assert config.learning_starts == 123


@pytest.mark.parametrize(
    "text, overrides, algorithm",
    [
        (PENDULUM + "algorithm: td3\n", {}, "td3"),  # the preset chose
        (PENDULUM, {"algorithm": "pretrain_td3"}, "pretrain_td3"),  # an override chose
        ("env_id: Pendulum-v1\n", {}, "td3"),  # no tree: TD3, the config's default
    ],
)
def test_no_recipe_when_an_algorithm_is_named_or_there_is_no_tree(
    tmp_path, text, overrides, algorithm
):
    config = load_preset(_preset(tmp_path, text), **overrides)
    assert config.recipe is None and config.algorithm == algorithm


def test_graft_train_says_which_recipe_in_one_line(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "other.txt").write_text("not empty")  # refused before Ray starts
    preset = _preset(tmp_path, PENDULUM)
    with pytest.raises(SystemExit):
        main(["train", "--preset", str(preset), "--run-dir", str(tmp_path / "run")])
    first = capsys.readouterr().err.splitlines()[0]
    assert first == (
        "graft train: preset task names a hardcoded_policy and no algorithm: graft's default "
        f"recipe for continuous actions, {recipe_description('continuous')} "
        "(docs/own-task.md, 'The default recipe'; set algorithm: to choose another)"
    )


def test_a_task_that_does_not_build_is_one_line_before_any_recipe(tmp_path):
    preset = _preset(tmp_path, "env_id: nowhere_pkg.envs:make\nhardcoded_policy: a.b:c\n")
    with pytest.raises(ValueError, match=r"^preset .*task.yaml: env_id='nowhere_pkg.envs:make'"):
        load_preset(preset)


@pytest.mark.long  # about 20 s on an idle 2-core machine, minutes on a loaded one
def test_the_recipe_with_a_standalone_actor_trains_through_the_service(ray_local, tmp_path):
    """`graft train --set backbone.residual=false`: IBRL's standalone actor in the recipe,
    through the real service (a local Ray, an actor, the replay server, the learner and the
    final selection), on a tiny budget."""
    preset = _preset(tmp_path, PENDULUM)
    tiny = [
        *("env_steps=600", "eval_every=300", "eval_episodes=1", "publish_every=20"),
        *("envs_per_actor=2", "steps_per_insert=4", "slack_env_steps=16"),
        *("td3.hidden_sizes=[32, 32]", "td3.batch_size=32", "td3.burn_in_updates=30"),
        *("td3.frozen_actor_updates=30", "selection.episodes=2", "backbone.residual=false"),
    ]
    run_dir = tmp_path / "run"
    args = ["train", "--preset", str(preset), "--run-dir", str(run_dir), "--no-progress"]
    main([*args, *(a for s in tiny for a in ("--set", s))])
    recorded = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert recorded["recipe"] == "continuous" and recorded["backbone"]["residual"] is False
    summary = json.loads((run_dir / "summary.json").read_text())
    assert 600 - 16 <= summary["env_steps"] <= 600
    assert summary["updates"] == 600 - 60 + 30  # a tenth of the budget prefills; the burn-in
    assert np.isfinite(summary["final_eval_return_mean"]) and "selection" in summary


def test_layer_norm_critics_reach_the_actors_numpy_copy(tmp_path):
    """`td3.critic_layer_norm`: the learner's twin critics get a LayerNorm before each
    hidden ReLU, and the critic the actors switch by (numpy) values actions as it does."""
    import torch

    from graft.registry import make_builder
    from service.core import as_arrays

    preset = _preset(tmp_path, PENDULUM + "recipe: continuous\n")
    config = load_preset(preset, **{"td3.critic_layer_norm": True, "td3.hidden_sizes": [16, 16]})
    builder = make_builder(config)
    learner, behaviour = builder.make_learner(), builder.make_behaviour(num_actors=1)
    assert any(isinstance(m, torch.nn.LayerNorm) for m in learner.critic.modules())
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in learner.actor.modules())
    for p in learner.critic.parameters():
        torch.nn.init.normal_(p, std=0.7)
    behaviour.load(as_arrays(learner.policy_state()))
    rng = np.random.default_rng(0)
    x, a = rng.normal(size=(7, 4)).astype(np.float32), rng.normal(size=(7, 1)).astype(np.float32)
    with torch.no_grad():
        expected = torch.min(*learner.critic(torch.as_tensor(x), torch.as_tensor(a))).numpy()
    np.testing.assert_allclose(behaviour.critic(x, a), expected, rtol=1e-5, atol=1e-5)
