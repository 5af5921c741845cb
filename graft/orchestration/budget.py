"""The env-step budget all actors of a run share: each phase's steps are claimed in
insert-batch chunks from one small Ray actor, instead of fixed shares per actor.

A fast actor simply claims more chunks, so every actor acts (and adopts weights) until
its phase's budget is spent. A dead actor's claims past what it is known to have stored
go back to the budget (`release`), to be claimed by the others and its replacement: at
most its chunk in flight (claimed, stored, not yet reported) is acted twice. An actor
asks for its next chunk while it acts the current one (`BudgetClaims`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Optional

import ray
from ray import ObjectRef

Range = tuple[int, int]
"""Steps [start, end) of one phase."""


@dataclass
class _Lease:
    """What one actor incarnation claimed, in order, and how much of it it stored."""

    grants: list[tuple[str, int, int]] = field(default_factory=list)
    """(table, start, count) in the order claimed: the actor stores them in this order."""
    stored: int = 0
    """Items the actor reported acknowledged (a prefix of `grants`)."""


class Budget:
    """The free step ranges of every phase and the claims made on them (pure Python)."""

    def __init__(self, totals: Mapping[str, int]) -> None:
        self._free: dict[str, list[Range]] = {t: [(0, n)] for t, n in totals.items() if n > 0}
        self._leases: dict[str, _Lease] = {}
        self._released: set[str] = set()
        """Leases of dead actors: a claim they sent before dying may still arrive."""

    def claim(self, lease: str, table: str, want: int, stored: int) -> Range:
        """Up to `want` steps of `table` from its lowest free range: (start, count)."""
        if want < 1:
            raise ValueError(f"want={want} must be >= 1")
        if lease in self._released:  # its actor is dead: nobody would act the steps
            return 0, 0
        record = self._leases.setdefault(lease, _Lease())
        record.stored = max(record.stored, stored)
        free = self._free.get(table, [])
        if not free:
            return 0, 0
        start, end = free[0]
        count = min(want, end - start)
        if start + count == end:
            free.pop(0)
        else:
            free[0] = (start + count, end)
        record.grants.append((table, start, count))
        return start, count

    def release(self, lease: str, stored: int) -> int:
        """Gives back what `lease` claimed beyond what it stored (the larger of `stored`
        and what it reported); returns that stored count."""
        record = self._leases.pop(lease, _Lease())
        self._released.add(lease)
        kept = max(record.stored, stored)
        skip = kept
        for table, start, count in record.grants:
            done = min(skip, count)
            skip -= done
            if done < count:
                self._give_back(table, (start + done, start + count))
        return kept

    def _give_back(self, table: str, span: Range) -> None:
        merged: list[Range] = []
        for start, end in sorted([*self._free.get(table, []), span]):
            if merged and start <= merged[-1][1]:
                merged[-1] = (merged[-1][0], max(end, merged[-1][1]))
            else:
                merged.append((start, end))
        self._free[table] = merged

    def left(self) -> dict[str, int]:
        """Unclaimed steps per table."""
        return {t: sum(e - s for s, e in spans) for t, spans in self._free.items()}


@ray.remote(num_cpus=0)
class StepBudget(Budget):
    """`Budget` as a Ray actor (calls run one at a time): the run's one shared budget."""

    def reset(self, totals: Mapping[str, int]) -> None:
        """Starts over as the next run's budget (a driver keeps it between runs: kept.py)."""
        Budget.__init__(self, totals)


BudgetHandle = Any
"""A Ray handle to a `StepBudget` (its `.remote` methods exist at run time only)."""


class BudgetClaims:
    """One actor incarnation's `StepClaims` on a `StepBudget`, under its lease name.

    Each claim that gets steps asks for the next chunk at once, so the round trip to the
    budget overlaps acting: an actor holds at most its chunk and the next one.
    """

    def __init__(self, budget: BudgetHandle, lease: str) -> None:
        self.budget, self.lease = budget, lease
        self._next: Optional[tuple[str, int, ObjectRef[Range]]] = None

    def __reduce__(self) -> tuple[type[BudgetClaims], tuple[BudgetHandle, str]]:
        return BudgetClaims, (self.budget, self.lease)  # a claim in flight stays here

    def claim(self, table: str, want: int, *, stored: int) -> tuple[int, int]:
        ahead, self._next = self._next, None
        if ahead is not None and ahead[:2] == (table, want):
            start, count = ray.get(ahead[2])
        else:
            if ahead is not None:  # its steps would never be acted: a caller's bug
                raise RuntimeError(f"a claim on {ahead[0]!r} is still held; act it first")
            start, count = ray.get(self.budget.claim.remote(self.lease, table, want, stored))
        if count:
            self._next = (table, want, self.budget.claim.remote(self.lease, table, want, stored))
        return int(start), int(count)
