"""Every preset through the real service (Ray actors -> replay server -> learner), tiny budgets."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml

from graft.config import load_preset, preset_names
from graft.orchestration.launcher import train
from learner.checkpoint import save_checkpoint
from learner.td3.config import TD3Config
from learner.td3.learning import TD3Learner
from tests.graft.test_travel_service import IDEAL_WORLD, SHORT_TRAVEL

TINY = {
    "learning_starts": 100,
    "eval_every": 200,
    "eval_episodes": 1,
    "publish_every": 20,
    "checkpoint_every": 10_000,
    # One actor process with two environments: every preset's path through the service
    # at the least CPU (several actors: test_end_to_end, test_supervision, test_budget).
    "num_actors": 1,
    "envs_per_actor": 2,
    "steps_per_insert": 4,
    "slack_env_steps": 16,
    "td3.hidden_sizes": [32, 32],
    "dqn.hidden_sizes": [32, 32],
}
DEMOS = {"pretrain.demo_steps": 200, "pretrain.pretrain_updates": 40}
BUDGETS = {
    # Offline only: the budget is the demonstrations; 40 updates on them, no online phase.
    "pendulum-offline-td3": {"env_steps": 200, **DEMOS},
    "pendulum-pretrained-td3": {"env_steps": 400, "td3.frozen_actor_updates": 20, **DEMOS},
    "pendulum-td3bc": {"env_steps": 400, **DEMOS},
    "pendulum-burnin": {"env_steps": 400, "td3.frozen_actor_updates": 20, **DEMOS},
    "pendulum-backbone": {
        "env_steps": 300,
        "td3.burn_in_updates": 30,
        "td3.frozen_actor_updates": 30,
    },
    # A step is a drop decision of the whole diamond tree: a few short episodes.
    # A decision comes every few hundred ticks of the whole tree: few of them, short worlds.
    # Ideal pacing: a mission's loading and ending seconds (real Malmo's, the preset's) were
    # most of this smoke run's time.
    "minecraft-drops": {
        "env_steps": 16,
        "learning_starts": 8,
        "dqn.batch_size": 8,
        "env_kwargs.max_ticks": 300,
        "env_kwargs.world_server": IDEAL_WORLD,
    },
    "minecraft-backbone": {"env_steps": 300, **SHORT_TRAVEL},
    "minecraft-options": {"env_steps": 300, **SHORT_TRAVEL},
    "pendulum-options-residual": {
        "env_steps": 300,
        "td3.burn_in_updates": 30,
        "td3.frozen_actor_updates": 30,
    },
}


def _teacher(folder) -> str:
    """A (barely trained) TD3 checkpoint standing in for a teacher run."""
    learner = TD3Learner(
        3, 1, np.array([-2.0]), np.array([2.0]), config=TD3Config(hidden_sizes=(32, 32)), seed=0
    )
    save_checkpoint(folder / "checkpoints", {"algorithm": learner.state_dict()}, updates=0)
    (folder / "config.yaml").write_text("td3:\n  hidden_sizes: [32, 32]\n")
    return str(folder)


# Minecraft presets wait on their world servers (start-up, worlds made): in the real-time
# part, so the waits overlap the CPU-bound parallel part.
PRESETS = [
    pytest.param(name, marks=pytest.mark.serial) if name.startswith("minecraft-") else name
    for name in preset_names()
]


@pytest.mark.parametrize("preset", PRESETS)
def test_preset_runs_through_the_service(preset, ray_local, tmp_path):
    overrides = {**TINY, **BUDGETS.get(preset, {"env_steps": 300})}
    if preset == "pendulum-backbone-teacher":
        overrides["backbone.teacher"] = _teacher(tmp_path / "teacher")
    config = load_preset(preset, **overrides)
    result = train(config, run_dir=tmp_path / "run", progress=False)
    s = result.summary
    # The learner may finish its updates (and stop the actors) up to the rate limiter's
    # slack before the actors inserted their last steps.
    assert config.env_steps - config.slack_env_steps <= s["env_steps"] <= config.env_steps
    pretrain = config.pretrain.pretrain_updates if config.algorithm == "pretrain_td3" else 0
    online = config.online_env_steps
    online_updates = (
        int((online - config.learning_starts) * config.updates_per_env_step) if online else 0
    )
    burn_in = config.td3.burn_in_updates
    expected_updates = pretrain + online_updates + burn_in
    assert s["updates"] == expected_updates
    assert np.isfinite(s["final_eval_return_mean"])
    assert (tmp_path / "run" / "learning_curve.png").stat().st_size > 0
    # learner.device: auto, recorded with the run.
    assert s["learner_device"] == ("cuda:0" if torch.cuda.is_available() else "cpu")
    recorded = yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())
    assert recorded["hardware"]["learner_device"] == s["learner_device"]


def test_checkpoints_keep_the_newest_or_all(tmp_path) -> None:
    for updates in range(5):
        save_checkpoint(tmp_path / "three", {"u": updates}, updates=updates)
        save_checkpoint(tmp_path / "all", {"u": updates}, updates=updates, keep=0)
    assert [p.name for p in sorted((tmp_path / "three").iterdir())] == [
        f"ckpt-{u:09d}.pt" for u in (2, 3, 4)
    ]
    assert len(list((tmp_path / "all").iterdir())) == 5


def test_train_flag_given_twice_is_named() -> None:
    from graft.cli import main

    with pytest.raises(SystemExit, match=r"--seed and --set seed=\.\.\. both given"):
        main(["train", "--preset", "pendulum-td3", "--seed", "1", "--set", "seed=2"])


def test_train_set_alone_overrides_a_flag_field() -> None:
    from graft.cli.parser import build_parser
    from graft.cli.train import train_overrides

    args = build_parser().parse_args(["train", "--set", "seed=2", "--set", "td3.gamma=0.9"])
    overrides = train_overrides(args)
    assert overrides["seed"] == 2 and overrides["td3.gamma"] == 0.9
    assert load_preset("pendulum-td3", **overrides).seed == 2
