"""Keeping a run alive through faults: the replay server restarted from its checkpoint
folder (`replay_host.supervised`), dead env actors replaced by new ones that take over the
rest of their work (of the run's shared step budget, or of a fixed share when no budget is
given).

A `Supervisor` thread checks both twice a second while the learner trains. Every
restart is said in one line (`note`) and counted (`faults/replay_restarts`,
`faults/actor_restarts`); the launcher logs the counters with the learner's metrics.
Exactly-once inserts keep the data right across a replay restart: an actor resends an
unacknowledged batch with the same (writer, sequence) and the restored server drops
what its log already holds.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Optional, Protocol

import ray
from ray.exceptions import ActorDiedError, ActorUnavailableError, GetTimeoutError, RayActorError

from actors.env_actor import Segment
from graft.orchestration.budget import BudgetClaims, BudgetHandle
from graft.replay_host.supervised import TooManyRestarts

CONFIRM_DEATH_S = 90.0
"""How long a replacement waits for Ray to call an unreachable actor dead (its node's)."""
CHECK_EVERY_S = 0.5
"""How often the supervisor looks at the replay server and the actors."""


def remaining_segments(segments: Sequence[Segment], done: int) -> list[Segment]:
    """What is left of `segments` once their first `done` steps are stored (in order)."""
    left = []
    for segment in segments:
        taken = min(done, segment.steps)
        done -= taken
        if segment.steps > taken:
            warmup = max(segment.warmup_steps - taken, 0)
            left.append(replace(segment, steps=segment.steps - taken, warmup_steps=warmup))
    return left


@dataclass
class _Slot:
    """One actor's share: its current incarnation and what earlier ones stored."""

    actor: Any
    run: Any  # the ObjectRef of its `run` call
    segments: list[Segment]
    stored_before: int = 0
    """Items earlier incarnations stored (the share left for this one excludes them)."""
    stored: int = 0
    """Items this incarnation reported stored (its last `report()`)."""
    report: Any = None  # a pending `report()` ObjectRef
    incarnation: int = 0
    stopped: bool = False
    """Stopped by the supervisor once the learner was done (`ActorFleet.reports`)."""


class ActorFleet:
    """The run's env actors; a dead one is replaced by a new actor that takes over the
    rest of its work (what its predecessor stored is known from its reports, polled
    by `check()`, and from its claims; at most the batch in flight at its death is acted
    again).

    With a `budget` (a `StepBudget`) every actor draws the steps of each phase from it,
    one insert batch at a time: a dead actor's claims past what it stored go back to the
    budget, and its replacement claims like any other actor. Without one, each actor acts
    its own fixed share and a replacement gets the rest of it.

    Args:
        make_actor: (actor index, incarnation) -> a started actor handle.
        segments: each actor's share, or with a budget the whole phases.
        count: how many actors.
        max_restarts: restarts allowed over all actors.
        start: start each actor's `run` on its share; False when someone else drives
            the actors (reproducible mode), and then they are not supervised.
        budget: the run's shared step budget (None: fixed shares).
    """

    def __init__(
        self,
        make_actor: Callable[[int, int], Any],
        segments: list[Segment],
        count: int,
        *,
        max_restarts: int,
        start: bool = True,
        budget: Optional[BudgetHandle] = None,
    ) -> None:
        self._make, self.max_restarts, self.restarts = make_actor, max_restarts, 0
        self.budget = budget
        self.slots = []
        for i in range(count):
            actor = make_actor(i, 0)
            slot = _Slot(actor, None, list(segments))
            if start:
                slot.run = self._start(i, slot)
            self.slots.append(slot)

    def _start(self, i: int, slot: _Slot) -> Any:
        if self.budget is None:
            return slot.actor.run.remote(slot.segments)
        return slot.actor.run.remote(slot.segments, BudgetClaims(self.budget, _lease(i, slot)))

    @property
    def handles(self) -> list[Any]:
        return [s.actor for s in self.slots]

    @property
    def runs(self) -> list[Any]:
        return [s.run for s in self.slots if s.run is not None]

    def check(self) -> list[str]:
        """Polls progress, replaces dead actors; returns a line per restart.

        Raises:
            TooManyRestarts: actors died more than `max_restarts` times.
            Exception: an actor's own error (its env failed): that is no fault to retry.
        """
        notes = []
        for i, slot in enumerate(self.slots):
            if slot.run is None:  # driven by someone else: not supervised
                continue
            if slot.report is not None and ray.wait([slot.report], timeout=0)[0]:
                try:
                    slot.stored = int(ray.get(slot.report)["replay/inserted"])
                except RayActorError:
                    pass  # its run call tells how it died
                slot.report = None
            if slot.report is None:
                slot.report = slot.actor.report.remote()
            if not ray.wait([slot.run], timeout=0)[0]:
                continue
            try:
                ray.get(slot.run)
                continue  # finished its share
            except RayActorError as error:
                notes.append(self._replace(i, slot, error))
        return notes

    def _replace(self, i: int, slot: _Slot, error: RayActorError) -> str:
        if self.restarts >= self.max_restarts:
            raise TooManyRestarts(
                f"env actor {i} died after {self.restarts} actor restarts "
                f"(actors.max_restarts={self.max_restarts}): {_first_line(error)}"
            )
        self.restarts += 1
        _confirm_death(slot.actor, error)
        ray.kill(slot.actor)
        if self.budget is not None:
            # Its claims past what it stored go back; the budget may know of more stored.
            slot.stored = int(ray.get(self.budget.release.remote(_lease(i, slot), slot.stored)))
        else:
            slot.segments = remaining_segments(slot.segments, slot.stored)
        slot.stored_before += slot.stored
        slot.stored, slot.report, slot.incarnation = 0, None, slot.incarnation + 1
        slot.actor = self._make(i, slot.incarnation)
        slot.run = self._start(i, slot)
        if self.budget is not None:
            left = sum(ray.get(self.budget.left.remote()).values())
            return (
                f"env actor {i} died ({_first_line(error)}); restarted it, {left:,} env steps "
                f"of the shared budget left to claim (actor restart {self.restarts})"
            )
        left = sum(s.steps for s in slot.segments)
        return (
            f"env actor {i} died ({_first_line(error)}); restarted it with {left:,} env "
            f"steps of its share left (actor restart {self.restarts})"
        )

    def reports(self, timeout_s: float) -> tuple[list[dict[str, Any]], list[str]]:
        """Every actor's final report (what earlier incarnations stored added to its
        ``env_steps``) once the learner is done, and a line per actor that had to be stopped.

        An actor still running after `timeout_s` waits on an insert the finished learner
        will never admit (its rate limiter holds the last inserts, e.g. when batches in
        flight at a replay restart were counted as sampled but never used): it is
        stopped, and its report is what it said it had stored.
        """
        ready, _ = ray.wait(self.runs, num_returns=len(self.runs), timeout=timeout_s)
        done = {ref.hex() for ref in ready}
        reports, notes = [], []
        for i, slot in enumerate(self.slots):
            report: Optional[dict[str, Any]] = None
            if slot.run.hex() in done:
                try:
                    report = ray.get(slot.run)
                except RayActorError:
                    pass
            if report is None:
                try:
                    slot.stored = int(
                        ray.get(slot.actor.report.remote(), timeout=10)["replay/inserted"]
                    )
                except (RayActorError, ray.exceptions.GetTimeoutError):
                    pass
                ray.kill(slot.actor)
                slot.stopped = True
                report = {"env_steps": slot.stored, "versions_seen": []}
                notes.append(
                    f"env actor {i} was still inserting after the learner finished; stopped "
                    f"it with {slot.stored_before + slot.stored:,} env steps of its share stored"
                )
            report["env_steps"] += slot.stored_before
            reports.append(report)
        return reports, notes

    def kill(self) -> None:
        for slot in self.slots:
            ray.kill(slot.actor)
        if self.budget is not None:
            ray.kill(self.budget)

    def release(self) -> list[Any]:
        """The actors of a run that ended well, for the next run to take (kept.py): all
        but those stopped."""
        return [s.actor for s in self.slots if not s.stopped]


def _lease(i: int, slot: _Slot) -> str:
    """The name one incarnation of actor `i` claims under."""
    return f"actor-{i}.{slot.incarnation}"


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


class Restartable(Protocol):
    """What the supervisor restarts: one replay server or all of a run's shards."""

    @property
    def restarts(self) -> int:
        """Restarts so far."""

    def check(self) -> Optional[str]:
        """Restarts what died; the line saying so (None if all is alive)."""


class Supervisor:
    """A thread checking the replay server and the actors every `CHECK_EVERY_S`.

    `note` is called with each restart's line (from the thread). An error the thread
    cannot recover from is kept and raised by `raise_error()` on the learner's thread.
    """

    def __init__(
        self,
        replay: Restartable,
        fleet: ActorFleet,
        note: Callable[[str], None],
    ) -> None:
        self.replay, self.fleet, self._note = replay, fleet, note
        self.error: Optional[BaseException] = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="supervisor", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.wait(CHECK_EVERY_S):
            try:
                line = self.replay.check()
                if line:
                    self._note(line)
                for line in self.fleet.check():
                    self._note(line)
            except BaseException as error:  # raised on the learner's thread
                self.error = error
                return

    def raise_error(self) -> None:
        if self.error is not None:
            raise self.error

    def counters(self) -> dict[str, float]:
        return {
            "faults/replay_restarts": self.replay.restarts,
            "faults/actor_restarts": self.fleet.restarts,
        }

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def _confirm_death(actor: Any, error: RayActorError) -> None:
    """Waits, at most CONFIRM_DEATH_S, until Ray calls an unreachable actor dead.

    An actor whose node vanished (its machine or container killed) is first only
    unreachable: Ray counts the node alive until its heartbeats have been missed for a
    while, and a replacement started before then may be placed on that node and never
    start. Once Ray has declared the node dead, the actor's calls fail with ActorDiedError.
    An actor that answers again was cut off for a moment; it is replaced all the same.
    """
    if not isinstance(error, ActorUnavailableError):
        return
    deadline = time.monotonic() + CONFIRM_DEATH_S
    while time.monotonic() < deadline:
        try:
            ray.get(actor.report.remote(), timeout=5)
            return
        except ActorDiedError:
            return
        except (ActorUnavailableError, GetTimeoutError):
            time.sleep(CHECK_EVERY_S)
