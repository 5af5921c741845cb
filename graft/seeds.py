"""The reset seeds a run plays, in three ranges that never meet.

A run with seed S resets its environments from

- training: the actors' environments, ``TRAINING + BLOCK·S + j`` for environment j of
  the run (j < BLOCK), and a replacement actor's (incarnation k ≥ 1) the same plus
  ``REPLACEMENT·k``;
- evaluation: the in-run evaluations and the final selection, episode i from
  ``EVALUATION + BLOCK·S + i`` (i < BLOCK): each seed its own episodes, so the selections
  of a benchmark's seeds are independent tests, not one set of starts seen five times;
- held out: the episodes a benchmark scores the final policy and the tree on, episode i
  from ``HELD_OUT + BLOCK·S + i`` (i < BLOCK), which no run plays.

Within a run the three never share a seed (for any S, with fewer than BLOCK environments,
evaluation episodes and held-out episodes); no two runs' evaluation episodes meet; and for
S < MAX_DISJOINT_SEED the three ranges of all seeds lie apart: held out below training
below evaluation.
Only the first reset of each environment is seeded; later resets draw from the
environment's own generator.
"""

from __future__ import annotations

BLOCK = 1_000
"""Width of one seed's block in each range: a run's environments, its evaluation episodes
and a benchmark's held-out episodes stay below it."""
TRAINING = 1_000_000
EVALUATION = 2_000_000
"""A run writes its first evaluation seed into RUN/summary.json (``evaluation_seed``); runs
trained before these blocks, without it, evaluated and selected on ``LEGACY_EVALUATION +
S + i``, which runs of nearby seeds shared."""
LEGACY_EVALUATION = 10_000
HELD_OUT = 100_000
REPLACEMENT = 1_000_000_000
MAX_DISJOINT_SEED = (TRAINING - HELD_OUT) // BLOCK
"""Below this seed, the held-out blocks of all seeds lie below the training blocks of all
seeds, and those below the evaluation blocks."""


def training_seed(seed: int, env_index: int, incarnation: int = 0) -> int:
    """First reset seed of the run's environment ``env_index`` (actor i's environment k is
    ``i·envs_per_actor + k``), in its actor's ``incarnation`` (0: the first process; a
    replacement explores from seeds of its own)."""
    if not 0 <= env_index < BLOCK:
        raise ValueError(f"environment {env_index}: a run has at most {BLOCK} environments")
    return TRAINING + BLOCK * seed + env_index + REPLACEMENT * incarnation


def evaluation_seed(seed: int) -> int:
    """First reset seed of the run's in-run evaluations and final selection (episode i:
    this + i, i < BLOCK)."""
    return EVALUATION + BLOCK * seed


def held_out_seed(seed: int) -> int:
    """First reset seed of a benchmark's held-out episodes for training seed ``seed``
    (episode i: this + i, i < BLOCK)."""
    return HELD_OUT + BLOCK * seed
