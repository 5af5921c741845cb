"""py_trees' blackboard is one store for the whole process: a tree built per environment
or per episode must take its namespace off it when it is done, or a long run's actors
and evaluator keep every one (the 4-client Minecraft soak's growing memory)."""

from __future__ import annotations

import gymnasium as gym
import py_trees
import pytest

from minecraft.agent import drop_env, travel_env
from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.leaves.context import CONTEXT_KEY, forget_namespace, new_namespace


def board_size() -> tuple[int, int, int]:
    board = py_trees.blackboard.Blackboard
    return len(board.storage), len(board.metadata), len(board.clients)


def test_forgetting_a_tree_removes_its_keys_and_leaves_and_nothing_else() -> None:
    before = board_size()
    kept, gone = new_namespace(), new_namespace()
    _, kept_ctx = build_tree(namespace=kept, seed=1)
    build_tree(namespace=gone, seed=2)
    grown = board_size()
    assert all(g > b for g, b in zip(grown, before, strict=True))
    forget_namespace(gone)
    storage = py_trees.blackboard.Blackboard.storage
    assert f"{gone}/{CONTEXT_KEY}" not in storage
    assert storage[f"{kept}/{CONTEXT_KEY}"] is kept_ctx
    forget_namespace(kept)
    assert board_size() == before


@pytest.mark.service  # a world server (in-process)
def test_travel_environments_made_and_closed_leave_the_blackboard_as_it_was() -> None:
    before = board_size()
    for seed in range(3):
        env = gym.make(travel_env.ENV_ID, world_seeds=(1000,))
        env.reset(seed=seed)
        env.step(env.action_space.sample())
        assert board_size() != before
        env.close()
        assert board_size() == before


@pytest.mark.service  # a world server (in-process)
def test_a_drops_episode_keeps_one_tree_on_the_blackboard_and_none_once_closed() -> None:
    before = board_size()
    env = gym.make(drop_env.ENV_ID, world_seeds=(2000,), max_ticks=400)
    try:
        env.reset(seed=0)
        one_tree = board_size()
        env.reset(seed=1)
        assert board_size() == one_tree
    finally:
        env.close()
    assert board_size() == before
