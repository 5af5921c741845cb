"""Reproducible mode: the learner advances the env actors itself, in a fixed order.

The default run is asynchronous: actors act as fast as the replay table's rate limiter
lets them, so which actor's batch lands first, which weights act on which steps and
which items a sample draws all depend on timing. In reproducible mode the learner loop
(learner/loop.py, `Lockstep`) asks actor 0, 1, ..., n-1, 0, ... for one insert batch at
a time, waits until the server has stored it, and then makes exactly the updates the
table's samples-per-insert ratio allows, drawing each batch only when it needs it from
a table whose sampler is seeded. Weights are published at fixed update counts and
adopted at the start of an actor's next batch; evaluations are logged as soon as they
finish. The same seed on the same machine then writes the same metrics.csv.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

import numpy as np
import ray
import torch

from actors.env_actor import Segment

ADVANCE_TIMEOUT_S = 600.0
"""How long one actor's insert batch may take before the run gives up (a hang, not a
slow environment: a batch is a few dozen steps)."""


class ActorRing:
    """`LockstepActors` (service/core.py) over `EnvActor` handles, asked in turn."""

    def __init__(self, actors: list[Any], segments: list[Segment]) -> None:
        self._actors = actors
        self._segments = {s.table: s for s in segments}
        self._next = 0
        self._finished: set[tuple[str, int]] = set()

    def advance(self, table: str, version: int) -> int:
        """The next actor that has steps left in `table` acts one insert batch."""
        segment = self._segments.get(table)
        if segment is None:  # a phase without env steps
            return 0
        for _ in range(len(self._actors)):
            i, self._next = self._next, (self._next + 1) % len(self._actors)
            if (table, i) in self._finished:
                continue
            ref = self._actors[i].advance.remote(segment, version)
            try:
                steps: int = ray.get(ref, timeout=ADVANCE_TIMEOUT_S)
            except ray.exceptions.GetTimeoutError:
                raise RuntimeError(
                    f"reproducible mode: actor {i} did not store its batch for table "
                    f"'{table}' within {ADVANCE_TIMEOUT_S:.0f} s (see replay.log)"
                ) from None
            if steps:
                return steps
            self._finished.add((table, i))
        return 0


def stalled() -> None:
    """The lock-step learner's watchdog: a batch it asks for is one the schedule allows,
    so a table that holds it back means the schedule and the rate limiter disagree."""
    raise RuntimeError(
        "reproducible mode: the replay table held back a batch the lock-step schedule "
        "allows (the rate limiter and the schedule disagree; see replay.log)"
    )


def deterministic(seed: int) -> Callable[[], None]:
    """Seeds Python's, numpy's and torch's global generators and makes torch pick
    deterministic kernels (or fail naming an op that has none); returns the function that
    restores torch's setting when the run ends."""
    previous = torch.are_deterministic_algorithms_enabled()
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    torch.use_deterministic_algorithms(True)

    def restore() -> None:
        torch.use_deterministic_algorithms(previous)

    return restore
