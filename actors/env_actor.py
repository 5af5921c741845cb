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

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Optional, SupportsFloat

import numpy as np
import ray
import torch

from actors.task import EnvSpec
from actors.tick_meter import TickMeter
from actors.writer import BackgroundWriter
from service.core import Behaviour, ReplayWriter, StepClaims, WeightSource

RECONNECT_TIMEOUT_S = 60.0
"""How long a lost environment's resets are retried before the actor gives up."""
StepOutcome = tuple[Any, SupportsFloat, bool, bool, dict[str, Any]] | ConnectionError
"""One environment's step: (obs, reward, terminated, truncated, info), or its world gone."""
MAX_BACKOFF_S = 5.0
"""The longest pause between two reset attempts (starting at 50 ms, doubling)."""
FLUSH_TIMEOUT_S = 60.0
"""How long the end of a run waits for queued inserts."""


class VectorStepper:
    """Steps `n` environments side by side; resets each one when its episode ends.

    Unlike gymnasium's vector autoreset, `next_obs` is always the true successor of
    `obs` (the final observation of an episode, never the first of the next one).

    An environment whose world went away raises `ConnectionError` from `step` or
    `reset`. The unfinished step has no successor, so it is no transition: `lost[i]`
    marks its row (filled with `obs`, truncated), and the environment is reset, retried
    with exponential backoff for up to `RECONNECT_TIMEOUT_S`.

    `streams[i]` names environment i's replay stream: the table links a stream's steps
    into episodes. A lost step ends no episode in the table, so the environment goes on
    in a new stream: the steps before and after the loss are never linked.

    `concurrent`: the environments' `step` calls run at once, one thread each, instead
    of one after another. For environments that wait on their own worlds (real-time
    Minecraft clients, each waiting for its world's next frame) a step of all `n` then
    takes the longest wait, not the sum; acting stays one batched policy call for all
    `n`. What still runs one at a time (the GIL: decoding each observation) grows with
    `n`, so a step's latency does too: see docs/tuning.md for clients per actor.
    """

    def __init__(self, env: EnvSpec, n: int, seed: int, *, concurrent: bool = False) -> None:
        self.envs = [env.make() for _ in range(n)]
        self._pool = ThreadPoolExecutor(n, thread_name_prefix="env-step") if concurrent else None
        self.meter = TickMeter(n)
        self.lost = np.zeros(n, bool)
        self.streams = np.arange(n, dtype=np.int64)
        self.connection_losses = self.reconnects = 0
        self._ready = np.zeros(n)  # when each environment's latest observation arrived
        self.obs = np.stack([self._reset(i, seed=seed + i) for i in range(n)])
        self.episode_returns = np.zeros(n)
        self.finished_returns: list[float] = []

    def _reset(self, i: int, seed: Optional[int] = None) -> np.ndarray:
        delay, deadline = 0.05, time.monotonic() + RECONNECT_TIMEOUT_S
        while True:
            try:
                obs, info = self.envs[i].reset(seed=seed)
                break
            except ConnectionError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(delay)
                delay = min(2 * delay, MAX_BACKOFF_S)
        self.meter.begin(i, info.get("tick"))
        self._ready[i] = time.perf_counter()
        return obs

    def _step_one(self, i: int, action: np.ndarray) -> tuple[float, StepOutcome]:
        """Steps environment i: (the actor's own time before its action left, the step's
        result or the ConnectionError of a world that went away)."""
        own_s = time.perf_counter() - self._ready[i]  # from observation to action
        try:
            result = self.envs[i].step(action)
        except ConnectionError as error:
            return own_s, error
        self._ready[i] = time.perf_counter()
        return own_s, result

    def step(self, actions: np.ndarray) -> dict[str, np.ndarray]:
        obs = self.obs.copy()
        next_obs = np.empty_like(obs)
        rewards = np.empty(len(self.envs), np.float32)
        terminated = np.empty(len(self.envs), bool)
        truncated = np.empty(len(self.envs), bool)
        self.lost[:] = False
        indices = range(len(self.envs))
        if self._pool is not None:
            results = list(self._pool.map(self._step_one, indices, actions))
        else:
            results = [self._step_one(i, a) for i, a in zip(indices, actions, strict=True)]
        for i, (own_s, result) in enumerate(results):
            if isinstance(result, ConnectionError):
                self.connection_losses += 1
                self.lost[i], next_obs[i], rewards[i] = True, obs[i], 0.0
                terminated[i], truncated[i] = False, True
                self.episode_returns[i] = 0.0
                self.streams[i] += len(self.envs)
                self.obs[i] = self._reset(i)
                self.reconnects += 1
                continue
            next_obs[i], rewards[i], terminated[i], truncated[i], info = result
            self.meter.step(i, info.get("tick"), own_s)
            self.episode_returns[i] += rewards[i]
            if terminated[i] or truncated[i]:
                self.finished_returns.append(float(self.episode_returns[i]))
                self.episode_returns[i] = 0.0
                self.obs[i] = self._reset(i)
            else:
                self.obs[i] = next_obs[i]
        return {
            "obs": obs.astype(np.float32),
            "reward": rewards,
            "terminated": terminated,
            "truncated": truncated,
            "next_obs": next_obs.astype(np.float32),
        }

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
        for env in self.envs:
            env.close()


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
    `nice`, when given, is the acting thread's CPU niceness: Ray starts workers at nice
    15 (`RAY_worker_niceness`), below every ordinary process, so a real-time actor on a
    busy machine would be starved; 0 asks for an ordinary share. Lowering niceness needs
    CAP_SYS_NICE or RLIMIT_NICE; without them the actor keeps its niceness and reports it
    (`actor/nice`). `concurrent_steps`: step the environments at once (`VectorStepper`).
    """

    def __init__(
        self,
        *,
        env: EnvSpec,
        num_envs: int,
        seed: int,
        replay: ReplayWriter,
        weights: WeightSource,
        behaviour: Behaviour,
        steps_per_insert: int,
        nice: Optional[int] = None,
        concurrent_steps: bool = False,
    ) -> None:
        torch.set_num_threads(1)
        self.stepper = VectorStepper(env, num_envs, seed, concurrent=concurrent_steps)
        self.rng = np.random.default_rng(seed)
        self.writer = BackgroundWriter(replay)
        self.weights = weights
        self.behaviour = behaviour
        self.steps_per_insert = steps_per_insert
        self.nice = nice
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)
        self.versions_seen: list[int] = []
        self.stats: list[dict[str, float]] = []
        self.env_steps = 0
        self._start: Optional[float] = None
        self._advanced: dict[str, int] = {}  # advance(): env steps acted per table
        self._window = (time.monotonic(), 0)  # measurement window: start, env steps then

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
        # Linux niceness is per thread: set it on the thread that acts.
        if self.nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)
            except OSError:
                pass  # not permitted: `actor/nice` shows what the actor got
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)

    def run(self, segments: list[Segment], claims: Optional[StepClaims] = None) -> dict[str, Any]:
        """Steps through `segments` in order (or until the learner says stop).

        Without `claims` each segment is this actor's own share. With them a segment is
        the whole phase, whose steps all actors share: the actor claims one insert batch
        at a time and acts exactly the steps it was given, until the phase is claimed.
        """
        self._set_priority()
        self.restart_meters()
        self._start = time.perf_counter()
        for segment in segments:
            if claims is not None:
                self._act_claimed(segment, claims)
                continue
            done = 0
            while done < segment.steps and not self.weights.stopped:
                buffer, steps = self._collect(segment, done, segment.steps)
                done += steps
                if len(buffer) < self.steps_per_insert and done < segment.steps:
                    break  # stopped mid-batch: see below
                self._insert(segment, buffer, max_pending=segment.pending_inserts)
        # A stopped run drops its unfinished batch: the learner no longer samples, and a
        # rate-limited table could hold its insert forever. Queued batches still go out.
        return self.finish()

    def _act_claimed(self, segment: Segment, claims: StepClaims) -> None:
        """Acts claimed chunks of `segment` until its phase is claimed or the learner stops."""
        want = self.steps_per_insert * len(self.stepper.envs)
        while not self.weights.stopped:
            # What the writer acknowledged so far: claims past it go back if we die.
            start, count = claims.claim(segment.table, want, stored=self.writer.inserted)
            if count == 0:
                return
            buffer, steps = self._collect(segment, start, start + count, exact=True)
            if steps < count:
                return  # stopped mid-batch (as in `run`)
            self._insert(segment, buffer, max_pending=segment.pending_inserts)

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
        buffer, steps = self._collect(segment, done, segment.steps)
        if not buffer:  # the learner said stop
            return 0
        self._advanced[segment.table] = done + steps
        self._insert(segment, buffer, max_pending=0)
        return steps

    def _collect(
        self, segment: Segment, done: int, end: int, *, exact: bool = False
    ) -> tuple[list[dict[str, np.ndarray]], int]:
        """Acts up to one insert batch (`steps_per_insert` vector steps) of `segment`, from
        its step `done` towards `end`; fewer when `end` is reached or the learner says
        stop. Steps below `segment.warmup_steps` use the warm-up policy. `exact`: keep no
        step past `end` (a claimed chunk); else the last vector step may pass it. Returns
        the per-step records and the env steps they hold."""
        n = len(self.stepper.envs)
        buffer: list[dict[str, np.ndarray]] = []
        steps = 0
        while (
            len(buffer) < self.steps_per_insert and done + steps < end and not self.weights.stopped
        ):
            warmup = done + steps < segment.warmup_steps
            if not warmup:
                self._wait_for_first_weights()
            self._adopt_new_weights()
            env_action, record = self.behaviour.act(self.stepper.obs, self.rng, warmup=warmup)
            record.update(self.stepper.step(env_action))
            # Columns computed on s' (e.g. the backbone's μ(s')); most add none.
            record.update(self.behaviour.next_columns(record["next_obs"]))
            lost = self.stepper.lost.copy()
            if exact:  # steps past the claimed chunk are not ours to keep: dropped as lost
                past = np.flatnonzero(~lost)[end - done - steps :]
                lost[past] = True
                # Their environments go on in new streams, as after a lost step.
                self.stepper.streams[past] += n
            self.behaviour.end_episodes(record["terminated"] | record["truncated"] | lost)
            version = -1 if warmup else self.weights.version  # -1: the warm-up policy
            record["policy_version"] = np.full(n, version, np.int64)
            record["acted_at"] = np.full(n, time.time())
            # Each environment is one stream: the table links its steps into episodes,
            # so sampled windows never mix environments or cross an episode end.
            record["_stream"] = self.stepper.streams.copy()
            if lost.any():  # a world went away mid-step: no successor, no transition
                record = {k: v[~lost] for k, v in record.items()}
            buffer.append(record)
            kept = n - int(lost.sum())
            steps += kept
            self.env_steps += kept
        return buffer, steps

    def _insert(
        self, segment: Segment, buffer: list[dict[str, np.ndarray]], *, max_pending: int
    ) -> None:
        batch = {k: np.concatenate([r[k] for r in buffer]) for k in buffer[0]}
        self.writer.insert(segment.table, batch, max_pending=max_pending)
        if stats := self.behaviour.stats():
            self.stats.append({"actor_steps": self.env_steps, **stats})

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
            "perf/process_cpu_s": time.process_time(),
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
