"""What an algorithm provides to a run: its phases, its learner and its actors' behaviour.

`train_here` (graft/orchestration/driver.py) wires a preset into a run like this::

    builder = make_builder(config)                     # graft/registry.py
    behaviour = builder.make_behaviour(num_actors=n)   # pickled to every actor
    phases = builder.phases()
    tables = preset_tables(config, phases=phases, signature=...)  # one table per phase
    algorithm = builder.make_learner(device=device, compile=compile)  # the learner's process
    EnvActor.remote(behaviour=behaviour, ...).run.remote(actor_segments(phases, n))
    LearnerLoop(algorithm, phases=phases, ...).run()   # phase.step(algorithm, batch)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Protocol

import torch

from learner.device import CPU, CompileMode
from service.core import Algorithm, Behaviour, Metrics, TensorBatch, UpdateStep


def update_step(algorithm: Algorithm, batch: TensorBatch) -> Metrics:
    """The step of most phases: the algorithm's own `update`."""
    return algorithm.update(batch)


@dataclass(frozen=True)
class Phase:
    """One stage of a run, seen from both sides of the replay table it goes through.

    Actors insert `env_steps` transitions into table `name`, the first `warmup_steps`
    with the behaviour's warm-up policy; the learner draws `updates` batches (windows
    of `sequence_length` steps when > 1) and hands each to `step(algorithm, batch)`.
    """

    name: str
    """Table name, and the phase's name in logs."""
    env_steps: int
    """Transitions the actors insert in this phase (over all actors)."""
    updates: int
    """Learner updates drawn from this phase's table."""
    min_size: int
    """Items the table holds before the first sample."""
    samples_per_insert: Optional[float] = None
    """Held sample/insert ratio (None: sample freely once `min_size` is reached)."""
    warmup_steps: int = 0
    """Leading env steps acted by the warm-up policy (uniform, μ(s) + ε, ε = 1)."""
    step: UpdateStep = update_step
    """The learning step each batch goes to."""
    acts_with_weights: bool = True
    """Actors need learner weights in this phase (the learner publishes at its start)."""
    sequence_length: int = 1
    """Steps per sampled window (1: single transitions)."""
    sample_credit: float = 0.0
    """Items the learner may sample at `min_size` beyond the held ratio (a burn-in of
    updates on the first data); the actors resume once it is spent."""


@dataclass(frozen=True)
class Budget:
    """The run-level numbers every builder shapes its phases from."""

    env_steps: int
    learning_starts: int
    updates_per_env_step: float
    slack_env_steps: int


def online_phase(
    budget: Budget, *, batch_size: int, env_steps: int, warmup: bool, burn_in_updates: int = 0
) -> Phase:
    """The standard off-policy phase: `learning_starts` steps fill the table, then one
    `updates_per_env_step` ratio of updates per env step, held by the rate limiter;
    `burn_in_updates` more run on the first `learning_starts` steps before actors go on."""
    return Phase(
        name="transitions",
        env_steps=env_steps,
        updates=int((env_steps - budget.learning_starts) * budget.updates_per_env_step)
        + burn_in_updates,
        min_size=budget.learning_starts,
        samples_per_insert=budget.updates_per_env_step * batch_size,
        warmup_steps=budget.learning_starts if warmup else 0,
        sample_credit=float(burn_in_updates * batch_size),
    )


class AgentBuilder(Protocol):
    """One algorithm's wiring (Acme's builder): config in, run objects out."""

    batch_size: int

    def phases(self) -> list[Phase]: ...
    def make_learner(
        self, *, device: torch.device = CPU, compile: CompileMode = "off"
    ) -> Algorithm:
        """The algorithm, its networks on `device`, compiled as `compile` says."""
        ...

    def make_behaviour(self, *, num_actors: int) -> Behaviour: ...
