"""Watching a run while the learner trains: fault lines said above the progress bar, the
restart counters logged with the metrics, and actors that failed or all finished early."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import ray
from ray.exceptions import RayActorError
from tqdm import tqdm

from graft.orchestration.supervision import ActorFleet, Supervisor
from learner.loop import LoopState
from service.metrics import MetricsLogger


def check_actors(runs: list[Any]) -> None:
    """Raises the error of an actor that failed; the learner would otherwise wait forever.
    An actor that died (its process or node gone) is the supervisor's to replace."""
    finished, _ = ray.wait(runs, num_returns=len(runs), timeout=0)
    for ref in finished:
        try:
            ray.get(ref)  # re-raises the actor's exception, with its traceback
        except RayActorError:
            return  # being replaced: its share is not done
    if len(finished) == len(runs):
        raise RuntimeError(
            "every actor finished, but the learner is still waiting for sampled batches: "
            "the rate limiter and the update budget disagree (see replay.log, or each "
            "shard's replay-shard-K.log)"
        )


def say_and_keep(notes: list[str], progress: bool) -> Callable[[str], None]:
    """A `note` that prints a fault line at once (above the progress bar) and keeps it."""

    def say(line: str) -> None:
        notes.append(line)
        message = f"graft train: {line}"
        if progress:
            tqdm.write(message, file=sys.stderr)
        else:
            print(message, file=sys.stderr, flush=True)

    return say


class FaultLog:
    """Logs the restart counters (`faults/...`) with the learner's metrics when they change."""

    def __init__(self, logger: MetricsLogger, supervisor: Supervisor, evaluator: Any) -> None:
        self.logger, self.supervisor, self.evaluator = logger, supervisor, evaluator
        self._last: dict[str, float] = {}

    def log(self, s: LoopState, *, always: bool = False) -> None:
        counters = {
            **self.supervisor.counters(),
            "faults/evaluator_restarts": self.evaluator.restarts,
        }
        if always or counters != self._last:
            self.logger.log(counters, env_steps=s.env_steps, updates=s.updates)
            self._last = counters


def watch(supervisor: Supervisor, fleet: ActorFleet, faults: FaultLog, s: LoopState) -> None:
    """The learner waits for a batch: a fault the supervisor could not mend, or actors that
    all finished while the learner still waits, end the run with their reason."""
    supervisor.raise_error()
    faults.log(s)
    check_actors(fleet.runs)
