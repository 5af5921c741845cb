"""The reset seeds a run plays, in three ranges that never meet.

A run with seed S resets its environments from

- training: the actors' environments, ``TRAINING + BLOCK·S + j`` for environment j of
  the run (j < BLOCK), and a replacement actor's (incarnation k ≥ 1) the same plus
  ``REPLACEMENT·k``;
- evaluation: the in-run evaluations and the final selection, episode i from
  ``EVALUATION + S + i``;
- held out: the episodes a benchmark scores the final policy and the tree on, episode i
  from ``HELD_OUT + BLOCK·S + i`` (i < BLOCK), which no run plays.

Within a run the three never share a seed (for any S, with fewer than BLOCK environments
and held-out episodes and fewer than ``HELD_OUT − EVALUATION`` evaluation episodes), and
for S < MAX_DISJOINT_SEED no run's training or evaluation seed is any run's held-out seed.
Only the first reset of each environment is seeded; later resets draw from the
environment's own generator.
"""

from __future__ import annotations

BLOCK = 1_000
"""Width of one seed's training and held-out blocks: a run's environments and a
benchmark's held-out episodes stay below it."""
EVALUATION = 10_000
TRAINING = 1_000_000
HELD_OUT = 100_000
REPLACEMENT = 1_000_000_000
MAX_DISJOINT_SEED = (TRAINING - HELD_OUT) // BLOCK
"""Below this seed, the held-out blocks of all seeds lie between the evaluation and the
training ranges of all seeds."""


def training_seed(seed: int, env_index: int, incarnation: int = 0) -> int:
    """First reset seed of the run's environment ``env_index`` (actor i's environment k is
    ``i·envs_per_actor + k``), in its actor's ``incarnation`` (0: the first process; a
    replacement explores from seeds of its own)."""
    if not 0 <= env_index < BLOCK:
        raise ValueError(f"environment {env_index}: a run has at most {BLOCK} environments")
    return TRAINING + BLOCK * seed + env_index + REPLACEMENT * incarnation


def evaluation_seed(seed: int) -> int:
    """First reset seed of the run's in-run evaluations and final selection (episode i:
    this + i)."""
    return EVALUATION + seed


def held_out_seed(seed: int) -> int:
    """First reset seed of a benchmark's held-out episodes for training seed ``seed``
    (episode i: this + i, i < BLOCK)."""
    return HELD_OUT + BLOCK * seed
