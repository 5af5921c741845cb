"""The three reset-seed ranges of a run (training, evaluation and selection, held out)
never share a seed, replacement actors included."""

from __future__ import annotations

import pytest

from bench import improve
from graft import seeds
from graft.config import load_preset

ENVS = seeds.BLOCK  # the most environments a run may have
EPISODES = 1_000  # evaluation / selection episodes, and held-out episodes


def ranges(seed: int, incarnations: int = 4) -> tuple[set[int], set[int], set[int]]:
    training = {seeds.training_seed(seed, j, k) for j in range(ENVS) for k in range(incarnations)}
    evaluation = set(range(seeds.evaluation_seed(seed), seeds.evaluation_seed(seed) + EPISODES))
    held_out = set(range(seeds.held_out_seed(seed), seeds.held_out_seed(seed) + EPISODES))
    return training, evaluation, held_out


@pytest.mark.parametrize("seed", [0, 1, 4, 10, 11, 99, 100, 899, 900, 12_345, 2**32 - 1])
def test_a_runs_training_evaluation_and_held_out_seeds_are_disjoint(seed):
    training, evaluation, held_out = ranges(seed)
    assert len(training) == ENVS * 4  # every environment of every incarnation its own seed
    assert not training & evaluation
    assert not training & held_out
    assert not evaluation & held_out


def test_below_the_bound_the_three_ranges_of_all_seeds_lie_apart():
    top = seeds.MAX_DISJOINT_SEED - 1
    held_out_high = seeds.held_out_seed(top) + EPISODES
    training_high = seeds.training_seed(top, ENVS - 1) + 1
    assert seeds.training_seed(0, 0) >= held_out_high  # held out < training
    assert seeds.evaluation_seed(0) >= training_high  # training < evaluation


@pytest.mark.parametrize("first", [0, 5, 899, 12_345])
def test_no_two_seeds_evaluate_or_select_on_the_same_episodes(first):
    """Each seed's selection is a test of its own: five seeds' selections do not reuse one
    set of starts (as 10,000 + S + i did, 26 of 30 episodes shared between any two)."""
    blocks = [
        set(range(seeds.evaluation_seed(s), seeds.evaluation_seed(s) + EPISODES))
        for s in range(first, first + 5)
    ]
    assert all(not a & b for i, a in enumerate(blocks) for b in blocks[i + 1 :])


def test_the_benchmark_scores_on_the_held_out_range_and_the_runs_evaluations():
    for seed in range(5):
        assert improve.final_seed(seed) == seeds.held_out_seed(seed)
        summary = {"seed": seed, "evaluation_seed": seeds.evaluation_seed(seed)}
        assert improve.in_run_seed(summary) == seeds.evaluation_seed(seed)
        # a run trained before its summary recorded the seed: the range it played then
        assert improve.in_run_seed({"seed": seed}) == seeds.LEGACY_EVALUATION + seed
    assert improve.EPISODES <= seeds.BLOCK


def test_a_run_with_more_environments_than_its_seed_block_is_refused():
    with pytest.raises(ValueError, match="envs_per_actor=4 must be <= 1000"):
        load_preset("pendulum-td3", num_actors=251)
    with pytest.raises(ValueError, match="at most 1000 environments"):
        seeds.training_seed(0, 1000)


def test_more_evaluation_or_selection_episodes_than_a_block_are_refused():
    with pytest.raises(ValueError, match="eval_episodes=1001 and selection.episodes=50 must be"):
        load_preset(improve.TASKS["pendulum"], eval_episodes=1001)
    with pytest.raises(ValueError, match="selection.episodes=1001 must be <= 1000"):
        load_preset(improve.TASKS["pendulum"], **{"selection.episodes": 1001})
    # With best_in_run the selection plays the episodes after the in-run ones.
    best = {"selection.best_in_run": True}
    load_preset(improve.TASKS["pendulum"], eval_episodes=950, **best)
    with pytest.raises(ValueError, match=r"selection.episodes=50 must be <= 1000 \(their sum"):
        load_preset(improve.TASKS["pendulum"], eval_episodes=951, **best)
