"""Reproducible mode's schedule: the actors insert, one batch at a time in a fixed order,
until the table's held ratio admits the learner's next update."""

from __future__ import annotations

from dataclasses import dataclass

from learner.agent import Phase
from service.core import LockstepActors


@dataclass(frozen=True)
class Lockstep:
    """Reproducible mode: the actors the loop advances, and the batch size that turns the
    table's held samples-per-insert into updates."""

    actors: LockstepActors
    batch_size: int


def updates_allowed(phase: Phase, inserted: int, *, batch_size: int) -> int:
    """Updates of `phase` its table's rate limiter holds for `inserted` items: none below
    `min_size`, then `samples_per_insert` items per insert beyond it plus the burn-in
    credit. (A phase without a ratio updates once its actors have finished.)"""
    if phase.samples_per_insert is None or inserted < phase.min_size:
        return 0
    samples = (inserted - phase.min_size) * phase.samples_per_insert + phase.sample_credit
    return int(samples // batch_size)


class LockstepFeed:
    """One phase's lock-step schedule: the actors insert, one batch at a time in a fixed
    order, until the held ratio admits the next update."""

    def __init__(self, lockstep: Lockstep, phase: Phase, *, first: int) -> None:
        self.lockstep, self.phase, self.first = lockstep, phase, first
        self.inserted = 0
        self.finished = False

    def until_allowed(self, update: int, version: int) -> int:
        """Advances the actors until the run's update number `update` is allowed (or
        they have finished the phase); returns the items in the phase's table."""
        version = version if self.phase.acts_with_weights else -1
        batch_size = self.lockstep.batch_size
        while (
            not self.finished
            and updates_allowed(self.phase, self.inserted, batch_size=batch_size)
            < update - self.first
        ):
            steps = self.lockstep.actors.advance(self.phase.name, version)
            self.inserted += steps
            self.finished = steps == 0
        return self.inserted
