"""The held-out tasks' trees (examples/heldout): each writes a valid action on every tick,
and does what its docstring says on an episode no bench run uses (reset seed 900,000)."""

from __future__ import annotations

# Imported at collection: importing MuJoCo starts a child process (ctypes finding OpenGL),
# which `make test-fast` refuses inside a test.
import gymnasium.envs.mujoco.hopper_v5  # noqa: F401
import numpy as np
import pytest

import graft

PRESETS = "examples/heldout/presets"


@pytest.mark.parametrize(
    ("task", "at_least"),
    [
        ("acrobot", -499.0),  # -1 a step: the tip gets above the bar before the time limit
        ("hopper", 1000.0),  # 1 a healthy step: it stays up all 1,000 steps
    ],
)
def test_a_held_out_tree_does_its_job(task, at_least) -> None:
    # Through graft's own policy for a tree, as the bench scores it.
    tree = graft.load_policy("hardcoded", preset=f"{PRESETS}/{task}.yaml")
    score = graft.evaluate(tree, episodes=1, seed=900_000).mean
    assert score >= at_least, (task, score)


def test_the_reacher_tree_beats_holding_still_on_the_same_episodes() -> None:
    tree = graft.load_policy("hardcoded", preset=f"{PRESETS}/reacher.yaml")
    reaching = graft.evaluate(tree, episodes=5, seed=900_000).mean
    still = graft.evaluate(
        lambda obs: np.zeros((len(obs), 2), np.float32), env="Reacher-v5", episodes=5, seed=900_000
    ).mean
    assert reaching > still + 2.0, (reaching, still)
