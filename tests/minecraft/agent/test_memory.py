"""What a long run's env actors and evaluator must not keep (the 4-client Minecraft soak's
growing memory): py_trees' blackboard is one store for the whole process, so a tree built
per environment or per episode takes its namespace off it when done; and a finished
mission's world is freed as soon as the next one starts, not at a full garbage collection
(which a process as large as an env actor seldom runs)."""

from __future__ import annotations

import gc
import weakref

import gymnasium as gym
import py_trees
import pytest

from minecraft.agent import drop_env, travel_env
from minecraft.agent.diamond_tree import build_tree
from minecraft.agent.leaves.context import CONTEXT_KEY, Context, forget_namespace, new_namespace
from minecraft.sim.world import World


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
    with pytest.raises(ValueError, match="not a tree's namespace"):
        forget_namespace(Context().namespace)  # never shared: would forget every tree
    assert storage[f"{kept}/{CONTEXT_KEY}"] is kept_ctx
    forget_namespace(kept_ctx.namespace)
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


@pytest.mark.service  # a world server (in-process)
def test_a_finished_missions_world_is_freed_without_the_garbage_collector() -> None:
    env = gym.make(travel_env.ENV_ID, world_seeds=(1000, 1001, 1002))
    gc.collect()
    # Worlds an earlier test left alive in this worker process are not this env's.
    others = [weakref.ref(o) for o in gc.get_objects() if type(o) is World]
    worlds: list[weakref.ref[World]] = []
    gc.disable()
    try:
        for seed in range(4):
            env.reset(seed=seed)
            env.step(env.action_space.sample())
            worlds += [
                weakref.ref(o)
                for o in gc.get_objects()
                if type(o) is World and all(r() is not o for r in worlds + others)
            ]
        alive = [r for r in worlds if r() is not None]
        assert len(worlds) == 4 and len(alive) == 1  # the mission in play
    finally:
        gc.enable()
        env.close()
