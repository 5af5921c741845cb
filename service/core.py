"""The contracts between graft's parts, each shown with the loop that calls it.

A seam between packages is typed with one of these protocols. This is the bottom layer:
it imports no other graft module, so every package may import it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Future
from typing import TYPE_CHECKING, Any, NotRequired, Optional, Protocol, TypedDict

import numpy as np

if TYPE_CHECKING:  # actors follow these contracts without loading torch
    import torch

Columns = dict[str, np.ndarray]
"""Replay columns of B steps, each [B, ...]; a sampled batch too."""
TensorBatch = dict[str, "torch.Tensor"]
"""A sampled batch's data columns as tensors, as a learning step takes them."""
Metrics = dict[str, float]
"""Namespaced scalars a learning step reports (`losses/critic`, ...)."""
Weights = dict[str, "torch.Tensor"]
"""The acting policy's parameters, as the learner publishes them."""
WeightArrays = dict[str, np.ndarray]
"""The same parameters as actors and the evaluator get them: numpy arrays of the same
names (they act without torch: actors/policy_net.py)."""


def as_arrays(weights: Mapping[str, Any]) -> WeightArrays:
    """Weights (tensors on any device, or arrays) as numpy arrays, without a copy where
    they are in host memory already: whoever keeps them copies (`ray.put`, `PolicyNet`)."""
    return {
        k: np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v)
        for k, v in weights.items()
    }


class ColumnSpec(TypedDict):
    """One column of a replay signature."""

    dtype: str
    shape: list[int]


class Behaviour(Protocol):
    """The policy an actor acts with: exploration, warm-up and the columns replay keeps.

    `EnvActor.run` (actors/env_actor.py) drives it, B environments at a time::

        behaviour.load(new_weights)  # when weights.poll() returns some
        action, record = behaviour.act(obs[envs], rng, warmup=..., envs=envs)
        record = stepper.step(action, envs, carry=record)   # obs, reward, ..., next_obs
        record.update(behaviour.next_columns(record["next_obs"], envs=stepper.stepped))
        behaviour.end_episodes(record["terminated"] | record["truncated"], envs=stepper.stepped)
        replay.insert(segment.table, batch)      # every few steps, then behaviour.stats()

    `envs` says which environments the rows are (None: environments 0..B-1, in order).
    Environments that step at their own pace (real-time clients) come in varying
    subsets, so whatever a behaviour keeps per environment it keeps by `envs`.

    `Evaluator.evaluate` (actors/evaluator.py) calls `load(weights)`, then `greedy(obs)`.
    """

    def columns(self) -> dict[str, ColumnSpec]:
        """Every column `act` and `next_columns` return, as a replay signature fragment."""

    def load(self, weights: WeightArrays) -> None:
        """Adopts published learner weights."""

    def act(
        self,
        obs: np.ndarray,
        rng: np.random.Generator,
        *,
        warmup: bool,
        envs: Optional[np.ndarray] = None,
    ) -> tuple[np.ndarray, Columns]:
        """Actions to apply for obs [B, ...] (`warmup`: the warm-up policy's), and columns
        holding at least `action`, the sampled action UNCLIPPED (importance ratios are
        taken on it; the environment clips), and `log_prob`, its log-likelihood."""

    def next_columns(self, next_obs: np.ndarray, envs: Optional[np.ndarray] = None) -> Columns:
        """Columns computed on s' (e.g. the backbone's μ(s')); {} for most behaviours."""

    def end_episodes(self, ended: np.ndarray, envs: Optional[np.ndarray] = None) -> None:
        """Told after each step which environments' episodes ended ([B] bool)."""

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions for evaluation, [B, ...]."""

    def stats(self) -> dict[str, float]:
        """Scalars about the behaviour since the last call (e.g. option usage), then reset."""


class ReplayWriter(Protocol):
    """Where an actor's steps go (`ReplayClient`, service/replay/client.py).

    `EnvActor.run` calls ``replay.insert(segment.table, batch)`` every `steps_per_insert`
    steps; it blocks while the table's rate limiter says wait, pacing actors to the learner.
    """

    def insert(
        self, table: str, columns: Mapping[str, np.ndarray], *, timeout: Optional[float] = None
    ) -> int:
        """Stores one batch of columns; returns the items stored (0 for a resent batch)."""


class WeightSource(Protocol):
    """The newest published weights, seen from an actor (`WeightSubscriber`, service/weights).

    `EnvActor.run` polls before each step (blocking only until the first weights, if
    acting needs them) and stops once `weights.stopped`; a poll that finds nothing new
    must cost next to nothing (`WeightSubscriber` fetches in the background)::

        if (new := weights.poll()) is not None:
            behaviour.load(new)
    """

    version: int
    """Version of the weights last returned by `poll` (-1: none yet)."""
    stopped: bool
    """The learner has finished: actors stop acting."""

    def poll(self, *, block_s: float = 0.0) -> Optional[WeightArrays]:
        """Weights newer than `version` if they arrived (waiting up to `block_s`), else None."""


class StepClaims(Protocol):
    """One actor's draw on the env-step budget all actors share (`BudgetClaims`,
    graft/orchestration/budget.py): a phase's steps are claimed one insert batch at a
    time, so no actor idles while another still has steps to act.

    `EnvActor.run` (actors/env_actor.py) claims each batch before it acts it::

        start, count = claims.claim(segment.table, steps_per_insert * B, stored=inserted)
        while count:  # steps [start, start + count) of the phase; below warmup_steps: warm-up
            act and insert exactly `count` steps, then claim again
    """

    def claim(self, table: str, want: int, *, stored: int) -> tuple[int, int]:
        """Up to `want` steps of `table`'s phase: (index of the first in the phase, how
        many); (0, 0) once the phase's budget is claimed. `stored` is how many items
        this actor's inserts have had acknowledged so far (all tables): what a dead
        actor claimed beyond it goes back to the budget."""


UpdateStep = Callable[["Algorithm", TensorBatch], Metrics]
"""One learning step on a batch. Each phase carries the step its batches go to:
`learner.agent.update_step` (the algorithm's `update`) unless it names another."""


class Algorithm(Protocol):
    """A learning algorithm, as `LearnerLoop.run` (learner/loop.py) drives it (and
    `restore` in graft/orchestration/resume.py resumes a run with `load_state_dict`)::

        for phase in phases:
            stream = open_stream(phase)
            while updates < end of phase:
                metrics = phase.step(algorithm, to_tensors(stream.next_within(timeout)))
                every publish_every:    publisher.publish(version, algorithm.policy_state())
                every checkpoint_every: save_checkpoint(dir, {"algorithm": algorithm.state_dict()})
    """

    def update(self, batch: TensorBatch) -> Metrics:
        """One learning step on a sampled batch; returns its metrics."""

    def policy_state(self) -> Weights:
        """Detached copies of the acting policy's weights, for the actors."""

    def state_dict(self) -> dict[str, Any]:
        """Everything a resumed run needs (networks, optimisers, counters); opaque to the loop."""

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores what `state_dict` returned."""


class SampleStream(Protocol):
    """Batches sampled from one table, fetched ahead (`SampleStream`, service/replay/client.py).

    `LearnerLoop.run` reads one per phase::

        stream = open_stream(phase)  # ReplayClient.sample_stream(phase.name, ...)
        batch = stream.next_within(STALL_CHECK_S)  # TimeoutError: ask the watchdog, retry
        env_steps, learner_wait_s = offset + stream.table_inserts, stream.wait_s
        stream.close()  # at the end of the phase
    """

    wait_s: float
    """Seconds the consumer has waited for batches so far."""
    table_inserts: int
    """Items inserted into the table, as of the last batch."""

    def next_within(self, timeout: Optional[float]) -> Columns:
        """The next batch; raises TimeoutError if none arrives within `timeout` seconds."""

    def close(self) -> None:
        """Stops fetching."""


class WeightPublisher(Protocol):
    """Where the learner publishes its policy (`BroadcastPublisher`, service/weights.py).

    `LearnerLoop.publish` calls ``publisher.publish(version, algorithm.policy_state())``
    before the first phase that acts with weights, every `publish_every` updates and at
    the end; versions only grow.
    """

    def publish(self, version: int, weights: Weights) -> None:
        """Makes `weights` the newest version every `WeightSource` will return."""


class EvalTag(TypedDict):
    """Where in the run evaluated weights come from."""

    env_steps: int
    updates: int
    wall_s: float


class Evaluation(TypedDict):
    """Greedy episode returns of one set of weights."""

    tag: EvalTag
    mean: float
    std: float
    stats: dict[str, float]  # what the behaviour counted while acting greedily
    returns: NotRequired[list[float]]  # episode by episode: reset seeds seed + first, + 1, ...


class Evaluator(Protocol):
    """Scores weights with greedy episodes, off the learner's thread (actors/evaluator.py).

    `LearnerLoop.run` submits weights and logs the results as they finish::

        pending.append(evaluator.evaluate(weights, episodes=eval_episodes, tag=tag))
        for future in [f for f in pending if f.done()]:
            state.evaluations.append(future.result())  # and logged: eval/return_mean
    """

    def evaluate(
        self, weights: Weights, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Future[Evaluation]:
        """Starts `episodes` greedy episodes with `weights`, the run's evaluation episodes
        `first`, `first` + 1, ...; the future holds their returns."""


class LockstepActors(Protocol):
    """Actors the learner advances itself, in reproducible mode
    (graft/orchestration/lockstep.py).

    `LearnerLoop` (learner/loop.py) then samples only what the held ratio allows::

        while updates < end of phase:
            while updates_allowed(phase, inserted, batch_size=...) <= updates:  # the held ratio
                inserted += actors.advance(phase.name, version)  # stored when it returns
            metrics = phase.step(algorithm, to_tensors(stream.next_within(timeout)))
    """

    def advance(self, table: str, version: int) -> int:
        """The next actor in a fixed order acts one insert batch into `table` with policy
        `version` (-1: none needed yet); returns the env steps stored (0: every actor has
        finished its share of the phase)."""
