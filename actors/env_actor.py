"""Ray actor stepping several gymnasium environments with the current behaviour policy.

It streams transitions (with the behaviour log-likelihood and policy version) to the
replay server and adopts newer weights whenever the learner publishes them. What it
acts with is a `Behaviour` (service/core.py); the actor itself knows no algorithm.

Any environment, including a real-time one (a Minecraft client whose world ticks on its
own), runs the same loop:

* in a run the steps of each phase are claimed from a budget all actors share
  (`StepClaims`), one insert batch at a time, so every actor acts until the phase is
  spent; alone (or driven by the learner in reproducible mode) a segment is its own share;
* inserts go out from a background thread (`BackgroundWriter`); a segment says how many
  insert batches may wait while acting goes on (0: wait for each, so a table's rate
  limiter paces acting exactly);
* an environment reporting its world clock as ``info["tick"]`` gets its skipped ticks
  metered, and every environment the actor's own time per step (`TickMeter`);
* an environment whose world goes away raises `ConnectionError`; the unfinished step is
  dropped and the environment reset with backoff until its world is back.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import ray

from actors.stepper import VectorStepper
from actors.task import EnvSpec
from actors.writer import BackgroundWriter
from service.core import Behaviour, ReplayWriter, StepClaims, WeightSource

__all__ = ["EnvActor", "Segment", "VectorStepper"]

FLUSH_TIMEOUT_S = 60.0
"""How long the end of a run waits for queued inserts."""


@dataclass(frozen=True)
class Segment:
    """A stretch of one actor's work: `steps` transitions into `table`, the first
    `warmup_steps` of them with the behaviour's warm-up policy.

    `pending_inserts` insert batches may wait for the background writer while acting goes
    on; with more, acting waits (back-pressure: no batch is dropped). 0 waits for each
    insert to be stored: a table whose rate limiter holds a samples-per-insert ratio then
    paces acting batch by batch, as it must (with a queue the actor would act that many
    batches ahead of what the limiter admitted, with older weights). Tables that never
    hold inserts back (`min_size`) can take a queue, so a real-time actor never waits on
    the network.
    """

    table: str
    steps: int
    warmup_steps: int = 0
    pending_inserts: int = 0


@ray.remote(num_cpus=0.25, max_concurrency=2)  # type: ignore[call-overload]  # task-only stubs
class EnvActor:
    """Collects transitions segment by segment with its behaviour policy: all of them in
    one `run()` call (the default, asynchronous mode), or one insert batch per
    `advance()` call when the learner drives it (reproducible mode).

    Two calls run at once: `report()` and `restart_meters()` answer while `run()` acts.
    `nice`, when given, is the CPU niceness of the threads that act and step the
    environments and of the replay writer's: Ray starts workers at nice
    15 (`RAY_worker_niceness`), below every ordinary process, so a real-time actor on a
    busy machine would be starved; 0 asks for an ordinary share. Lowering niceness needs
    CAP_SYS_NICE or RLIMIT_NICE; without them the actor keeps its niceness and reports it
    (`actor/nice`). `async_envs`: each environment steps at its own pace
    (`VectorStepper`'s asynchronous mode, for real-time clients).
    """

    def __init__(
        self,
        *,
        env: EnvSpec | Sequence[EnvSpec],
        num_envs: int,
        seed: int,
        replay: ReplayWriter,
        weights: WeightSource,
        behaviour: Behaviour,
        steps_per_insert: int,
        nice: Optional[int] = None,
        async_envs: bool = False,
    ) -> None:
        self.nice = nice
        # The threads started here (environment steps, the replay writer) do most of a
        # real-time actor's work: they take the acting niceness, as `run()`'s thread does
        # (a new thread inherits its creator's), and Ray's thread gets its own back.
        ray_nice = os.getpriority(os.PRIO_PROCESS, 0)
        self._set_priority()
        try:
            self.stepper = VectorStepper(env, num_envs, seed, asynchronous=async_envs)
            self.writer = BackgroundWriter(replay)
        finally:
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, 0, ray_nice)
        self.rng = np.random.default_rng(seed)
        self.weights = weights
        self.behaviour = behaviour
        self.steps_per_insert = steps_per_insert
        self.acting_nice = ray_nice
        self.versions_seen: list[int] = []
        self.stats: list[dict[str, float]] = []
        self.env_steps = 0
        self._start: Optional[float] = None
        self._advanced: dict[str, int] = {}  # advance(): env steps acted per table
        self._window = (time.monotonic(), 0)  # measurement window: start, env steps then
        self._cpu_before = 0.0  # this process's CPU before this run (a kept actor's earlier runs)

    def reset(self, **arguments: Any) -> None:
        """Sets up for another run as a new actor would, from a new actor's `arguments`,
        after closing this run's environments and writer: a driver keeps its actors
        between runs (graft/orchestration/kept.py)."""
        self.close()
        type(self).__init__(self, **arguments)
        self._cpu_before = time.process_time()

    def _adopt_new_weights(self, block_s: float = 0.0) -> None:
        weights = self.weights.poll(block_s=block_s)
        if weights is not None:
            self.behaviour.load(weights)
            self.versions_seen.append(self.weights.version)

    def _wait_for_first_weights(self) -> None:
        """Blocks until the learner publishes (it may pre-train first) or says stop."""
        while self.weights.version < 0 and not self.weights.stopped:
            self._adopt_new_weights(block_s=5.0)

    def _set_priority(self) -> None:
        # Linux niceness is per thread: this one's, inherited by the threads it starts.
        if self.nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)
            except OSError:
                pass  # not permitted: `actor/nice` shows what the actor got
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)

    def run(self, segments: list[Segment], claims: Optional[StepClaims] = None) -> dict[str, Any]:
        """Steps through `segments` in order (or until the learner says stop).

        Without `claims` each segment is this actor's own share, acted exactly. With them
        a segment is the whole phase, whose steps all actors share: the actor claims one
        insert batch at a time and acts exactly the steps it was given, until the phase is
        claimed.
        """
        self._set_priority()
        self.restart_meters()
        self._start = time.perf_counter()
        base = 0  # the run's env steps before this segment (claimed mode: all actors')
        for segment in segments:
            if claims is not None:
                self._act_claimed(segment, claims, base)
                base += segment.steps
                continue
            done = 0
            while done < segment.steps and not self.weights.stopped:
                buffer, steps, whole = self._collect(segment, done, segment.steps, exact=True)
                done += steps
                if not whole:
                    break  # stopped mid-batch: see below
                self._insert(segment, buffer, max_pending=segment.pending_inserts)
        # A stopped run drops its unfinished batch: the learner no longer samples, and a
        # rate-limited table could hold its insert forever. Queued batches still go out.
        return self.finish()

    def _act_claimed(self, segment: Segment, claims: StepClaims, base: int) -> None:
        """Acts claimed chunks of `segment` until its phase is claimed or the learner stops;
        `base`: the run's env steps before the segment."""
        want = self.steps_per_insert * len(self.stepper.envs)
        while not self.weights.stopped:
            # What the writer acknowledged so far: claims past it go back if we die.
            start, count = claims.claim(segment.table, want, stored=self.writer.inserted)
            if count == 0:
                return
            buffer, steps, _ = self._collect(segment, start, start + count, exact=True)
            if steps < count:
                return  # stopped mid-batch (as in `run`)
            self._insert(
                segment, buffer, max_pending=segment.pending_inserts, run_steps=base + start + count
            )

    def advance(self, segment: Segment, version: int) -> int:
        """Reproducible mode: acts one insert batch of `segment` with policy `version`
        (-1: none needed yet), and returns the env steps stored once the server has them
        (0: this actor's share of the segment is done).

        The learner calls this for one actor at a time and publishes only between calls,
        so which weights act on which steps is fixed by the call order, not by timing.
        """
        if self._start is None:
            self._start = time.perf_counter()
        done = self._advanced.get(segment.table, 0)
        if done >= segment.steps:
            return 0
        while self.weights.version < version and not self.weights.stopped:
            self._adopt_new_weights(block_s=5.0)
        buffer, steps, _ = self._collect(segment, done, segment.steps)
        if not buffer:  # the learner said stop
            return 0
        self._advanced[segment.table] = done + steps
        self._insert(segment, buffer, max_pending=0)
        return steps

    def _collect(
        self, segment: Segment, done: int, end: int, *, exact: bool = False
    ) -> tuple[list[dict[str, np.ndarray]], int, bool]:
        """Acts up to one insert batch (`steps_per_insert` steps of every environment) of
        `segment`, from its step `done` towards `end`; fewer when `end` is reached or the
        learner says stop. Steps below `segment.warmup_steps` use the warm-up policy.
        `exact`: keep no step past `end` (a claimed chunk); else the last step of the
        environments may pass it. Returns the per-step records, the env steps they hold,
        and whether the batch is whole (False: the learner said stop first)."""
        stepper = self.stepper
        n = len(stepper.envs)
        wanted = self.steps_per_insert * n
        buffer: list[dict[str, np.ndarray]] = []
        steps = 0
        while steps < wanted and not self.weights.stopped:
            left = end - (done + steps + stepper.in_flight)
            envs = stepper.idle if left > 0 else np.zeros(0, np.int64)
            if exact and stepper.asynchronous:  # never more in flight than the chunk has left
                envs = envs[: max(left, 0)]
            if len(envs) == 0 and stepper.in_flight == 0:
                break  # `end` is reached
            warmup = done + steps < segment.warmup_steps
            if not warmup:
                self._wait_for_first_weights()
            self._adopt_new_weights()
            env_action, record = self._act(envs, warmup)
            record = stepper.step(env_action, envs, carry=record)
            stepped, lost = stepper.stepped, stepper.lost.copy()
            # Columns computed on s' (e.g. the backbone's μ(s')); most add none.
            record.update(self.behaviour.next_columns(record["next_obs"], envs=stepped))
            if exact:  # steps past the claimed chunk are not ours to keep: dropped as lost
                past = np.flatnonzero(~lost)[max(end - done - steps, 0) :]
                lost[past] = True
                # Their environments go on in new streams, as after a lost step.
                stepper.streams[stepped[past]] += n
            ended = record["terminated"] | record["truncated"] | lost
            self.behaviour.end_episodes(ended, envs=stepped)
            # Each environment is one stream (`_stream`): the table links its steps into
            # episodes, so sampled windows never mix environments or cross an episode end.
            if lost.any():  # a world went away mid-step: no successor, no transition
                record = {k: v[~lost] for k, v in record.items()}
            if len(record["reward"]):
                buffer.append(record)
            kept = len(record["reward"])
            steps += kept
            self.env_steps += kept
        whole = steps >= wanted or done + steps >= end
        return buffer, steps, whole

    def _act(self, envs: np.ndarray, warmup: bool) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """The behaviour's actions for environments `envs`, and the columns their rows
        keep: its own, the policy version acting (-1: the warm-up policy) and when."""
        if len(envs) == 0:  # every environment is still stepping (asynchronous)
            return np.zeros((0,)), {}
        obs = self.stepper.obs[envs]
        env_action, record = self.behaviour.act(obs, self.rng, warmup=warmup, envs=envs)
        version = -1 if warmup else self.weights.version
        record["policy_version"] = np.full(len(envs), version, np.int64)
        record["acted_at"] = np.full(len(envs), time.time())
        return env_action, record

    def _insert(
        self,
        segment: Segment,
        buffer: list[dict[str, np.ndarray]],
        *,
        max_pending: int,
        run_steps: Optional[int] = None,
    ) -> None:
        """Queues `buffer` for the table, and the behaviour's scalars with where the run
        stands: `run_steps`, all actors' env steps up to this batch's end when the actors
        share a budget (else the launcher scales this actor's own steps)."""
        if not buffer:
            return
        batch = {k: np.concatenate([r[k] for r in buffer]) for k in buffer[0]}
        self.writer.insert(segment.table, batch, max_pending=max_pending)
        if stats := self.behaviour.stats():
            at = {"actor_steps": self.env_steps}
            if run_steps is not None:
                at["run_steps"] = run_steps
            self.stats.append({**at, **stats})

    def finish(self) -> dict[str, Any]:
        """Sends what is queued; the actor's report of the whole run."""
        self.writer.flush(timeout_s=FLUSH_TIMEOUT_S)
        return {
            "env_steps": self.env_steps,
            "wall_s": time.perf_counter() - (self._start or time.perf_counter()),
            "insert_s": self.writer.wait_s,
            "versions_seen": self.versions_seen,
            "episode_returns": self.stepper.finished_returns,
            "behaviour_stats": self.stats,
            **self.report(),
        }

    def restart_meters(self) -> None:
        """Start a new measurement window for `report()` (ticks, latency, rates)."""
        self.stepper.meter.restart()
        self._window = (time.monotonic(), self.env_steps)

    def report(self) -> dict[str, Any]:
        """Namespaced counters, and rates over the current measurement window."""
        t0, steps0 = self._window
        wall = max(time.monotonic() - t0, 1e-9)
        meter = self.stepper.meter.metrics()
        out: dict[str, Any] = {
            "actor/env_steps": self.env_steps,
            "actor/nice": self.acting_nice,
            "perf/measure_s": wall,
            "perf/steps_per_s": (self.env_steps - steps0) / wall,
            **meter,
            "net/connection_losses": self.stepper.connection_losses,
            "net/reconnects": self.stepper.reconnects,
            "replay/inserted": self.writer.inserted,
            "replay/insert_wait_s": self.writer.waited_s(),
            "replay/insert_call_s": self.writer.insert_call_s(),
            "replay/insert_calls": self.writer.insert_calls,
            "replay/fastest_insert_s": self.writer.fastest_insert_s,
            "perf/process_cpu_s": time.process_time() - self._cpu_before,
            "policy/version": self.weights.version,
            "policy/versions_adopted": len(self.versions_seen),
        }
        if "perf/ticks_seen" in meter:
            ticks = meter["perf/ticks_seen"] + meter["perf/ticks_skipped"]
            out["perf/world_ticks_per_s"] = ticks / wall
        return out

    def close(self) -> None:
        """Send what is queued, then close the environments (their world connections)."""
        self.writer.close(timeout_s=FLUSH_TIMEOUT_S)
        self.stepper.close()
