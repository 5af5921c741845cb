"""`minecraft-backbone` through the service at a tiny budget: 2 Ray actors, each stepping
its own simulated world server over MalmoEnv, stream transitions to a real gRPC replay
server; the backbone TD3 learner trains on them and its weights come back to the actors."""

from __future__ import annotations

import numpy as np
import pytest

from graft.config import load_preset
from graft.orchestration.launcher import train

IDEAL_WORLD = "minecraft.sim.server:ideal_world_server"
"""A simulated world without real Malmo's loading and ending seconds."""
SHORT_TRAVEL = {"env_kwargs.max_ticks": 200, "env_kwargs.world_server": IDEAL_WORLD}
"""Short missions (an evaluation plays one to its end) in ideally paced worlds: the
service's path is under test, real Malmo's pacing has tests of its own."""
TINY = {
    "num_actors": 2,
    "env_steps": 600,
    "learning_starts": 200,
    "updates_per_env_step": 0.5,
    "slack_env_steps": 64,
    "steps_per_insert": 16,
    "publish_every": 20,
    "eval_every": 300,
    "eval_episodes": 1,
    "checkpoint_every": 10_000,
    "td3.hidden_sizes": [32, 32],
    "td3.batch_size": 32,
    "env_kwargs.ticks_per_step": 2,
    **SHORT_TRAVEL,
}


def test_minecraft_backbone_smoke_two_clients(ray_local, tmp_path) -> None:
    config = load_preset("minecraft-backbone", **TINY)
    assert config.envs_per_actor == 1  # one simulated world per client
    result = train(config, run_dir=tmp_path / "run", progress=False)
    s = result.summary
    assert config.env_steps - config.slack_env_steps <= s["env_steps"] <= config.env_steps
    assert s["updates"] == int((600 - 200) * 0.5)
    # Both clients acted with learner weights (the broadcast reached every actor).
    assert len(s["actor_env_steps"]) == 2
    assert all(n >= 1 for n in s["actor_versions_adopted"])
    assert np.isfinite(s["final_eval_return_mean"])
    assert (tmp_path / "run" / "learning_curve.png").stat().st_size > 0
    assert "ticks_per_step: 2" in (tmp_path / "run" / "config.yaml").read_text()


def test_minecraft_preset_refuses_bad_config_naming_the_field() -> None:
    with pytest.raises(ValueError, match="correction_limit"):
        load_preset("minecraft-backbone", **{"backbone.correction_limit": 0.0})
    with pytest.raises(ValueError, match="envs_per_actor"):
        load_preset("minecraft-backbone", envs_per_actor=0)
