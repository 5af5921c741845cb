"""Several environments of one actor, stepped in lock-step or each at its own pace.

`VectorStepper` steps `n` environments and resets each one when its episode ends.
Unlike gymnasium's vector autoreset, `next_obs` is always the true successor of `obs`
(the final observation of an episode, never the first of the next one).

Lock-step (the default) suits environments that answer at once (Pendulum): every
`step()` steps all `n` and returns `n` rows, in order, so a seed fixes everything.

`asynchronous` suits environments that wait on worlds of their own (real-time Minecraft
clients, each world ticking on its own clock): each environment steps in a thread of
its own, and `step()` returns as soon as *any* of them has its next observation, with
the rows of every one finished by then. The actor then acts for just those (one batched
policy call) and steps them again, while the others still wait for their ticks. A
client is never held back by another one's slower tick or its mission's reset (which
runs in the client's own thread): in lock-step, each step of all `n` took the longest
of their waits, and clients whose tick came early skipped the next one.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Optional, SupportsFloat

import numpy as np

from actors.task import EnvSpec
from actors.tick_meter import TickMeter
from service.core import Columns

RECONNECT_TIMEOUT_S = 60.0
"""How long a lost environment's resets are retried before the actor gives up."""
MAX_BACKOFF_S = 5.0
"""The longest pause between two reset attempts (starting at 50 ms, doubling)."""

GATHER_S = 0.002
"""Asynchronous: after the first environment finishes, how long to wait for each next one
before acting (a step's latency grows by this much per environment gathered)."""

Reset = tuple[Any, Optional[int]]
"""A new episode's first observation and its world clock (None: the env reports none)."""


class _Outcome:
    """One environment's finished step, as its thread left it."""

    __slots__ = ("env", "own_s", "result", "reset", "ready_at")

    def __init__(self, env: int, own_s: float) -> None:
        self.env, self.own_s = env, own_s
        self.result: tuple[Any, SupportsFloat, bool, bool, dict[str, Any]] | None = None
        self.reset: Optional[Reset] = None  # the next episode's start, when this one ended
        self.ready_at = 0.0


class VectorStepper:
    """Steps `n` environments; resets each one when its episode ends.

    An environment whose world went away raises `ConnectionError` from `step` or
    `reset`. The unfinished step has no successor, so it is no transition: its row is
    marked in `lost` (filled with `obs`, truncated), and the environment is reset,
    retried with exponential backoff for up to `RECONNECT_TIMEOUT_S`.

    `streams[i]` names environment i's replay stream: the table links a stream's steps
    into episodes. A lost step ends no episode in the table, so the environment goes on
    in a new stream: the steps before and after the loss are never linked.

    Args:
        env: how to make each environment, or environment i's at `env[i]` (e.g. each in
            a Minecraft client of its own).
        n: how many.
        seed: environment i's first reset uses `seed + i`.
        asynchronous: each environment at its own pace (module docstring).
    """

    def __init__(
        self, env: EnvSpec | Sequence[EnvSpec], n: int, seed: int, *, asynchronous: bool = False
    ) -> None:
        specs = [env] * n if isinstance(env, EnvSpec) else list(env)
        if len(specs) != n:
            raise ValueError(f"{len(specs)} environment specs for {n} environments")
        self.envs = [spec.make() for spec in specs]
        self._pool = ThreadPoolExecutor(n, thread_name_prefix="env-step") if asynchronous else None
        self.meter = TickMeter(n)
        self.streams = np.arange(n, dtype=np.int64)
        self.connection_losses = self.reconnects = 0
        self._ready_at = np.zeros(n)  # when each environment's latest observation arrived
        # Asynchronous: the first missions load side by side (a real one takes seconds).
        resets = (
            list(self._pool.map(lambda i: self._reset(i, seed=seed + i), range(n)))
            if self._pool is not None
            else [self._reset(i, seed=seed + i) for i in range(n)]
        )
        now = time.perf_counter()
        self.obs = np.stack([self._begin(i, reset, now) for i, reset in enumerate(resets)])
        self.episode_returns = np.zeros(n)
        self.finished_returns: list[float] = []
        self.stepped = np.arange(n)
        """The environments of the rows the last `step()` returned (at first: all)."""
        self.lost = np.zeros(n, bool)
        """Rows of the last `step()` whose world went away: no transition."""
        self._in_flight: dict[int, dict[str, np.ndarray]] = {}  # env -> its carry row
        self._done: queue.SimpleQueue[_Outcome | BaseException] = queue.SimpleQueue()

    @property
    def idle(self) -> np.ndarray:
        """The environments whose observation (`obs[idle]`) awaits an action: those the
        last `step()` returned (the others are still stepping)."""
        return self.stepped

    @property
    def asynchronous(self) -> bool:
        """Each environment at its own pace (module docstring)."""
        return self._pool is not None

    @property
    def in_flight(self) -> int:
        """Environments stepping now (asynchronous only), their rows not returned yet."""
        return len(self._in_flight)

    def _reset(self, i: int, seed: Optional[int] = None) -> Reset:
        delay, deadline = 0.05, time.monotonic() + RECONNECT_TIMEOUT_S
        while True:
            try:
                obs, info = self.envs[i].reset(seed=seed)
                return obs, info.get("tick")
            except ConnectionError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(delay)
                delay = min(2 * delay, MAX_BACKOFF_S)

    def _begin(self, i: int, reset: Reset, ready_at: float) -> Any:
        """Environment i's new episode, its first observation there since `ready_at`."""
        self.meter.begin(i, reset[1])
        self._ready_at[i] = ready_at
        return reset[0]

    def _advance(self, i: int, action: np.ndarray, sent_at: Optional[float] = None) -> _Outcome:
        """Environment i's step, and its reset when the episode ended or the world went
        away (in its own thread when asynchronous: the others go on meanwhile)."""
        sent_at = time.perf_counter() if sent_at is None else sent_at
        out = _Outcome(i, sent_at - self._ready_at[i])  # from observation to action
        try:
            out.result = self.envs[i].step(action)
        except ConnectionError:
            out.reset = self._reset(i)
        else:
            if out.result[2] or out.result[3]:
                out.reset = self._reset(i)
        out.ready_at = time.perf_counter()
        return out

    def step(
        self,
        actions: np.ndarray,
        envs: Optional[np.ndarray] = None,
        carry: Optional[Columns] = None,
    ) -> dict[str, np.ndarray]:
        """Steps environments `envs` (default: all, in order; asynchronous: some of
        `idle`) with `actions`, and returns the finished rows: `obs`, `reward`,
        `terminated`, `truncated`, `next_obs`, `_stream`, and each `carry` column (one
        row per stepped environment, e.g. the behaviour's columns) on its own row.
        `stepped` says whose rows they are, `lost` which are no transition.

        Lock-step: the rows of `envs`, in order. Asynchronous: the rows of whichever
        environments have finished when the first one does (none when nothing steps).
        """
        envs = self.idle if envs is None else np.asarray(envs, dtype=np.int64)
        carry = carry or {}
        if self._pool is None:
            outcomes = [self._advance(int(i), a) for i, a in zip(envs, actions, strict=True)]
            return self._rows(outcomes, [carry])
        now = time.perf_counter()
        for j, i in enumerate(envs):
            self._in_flight[int(i)] = {k: v[j : j + 1] for k, v in carry.items()}
            self._pool.submit(self._advance_into_done, int(i), actions[j], now)
        if not self._in_flight:
            self.stepped = np.zeros(0, np.int64)
            return self._rows([], [])
        finished = [self._finished(self._done.get())]
        # Worlds that tick in step (missions started together) finish within a few
        # milliseconds of each other: gather them into one batch (one policy call for
        # all), waiting at most GATHER_S for each next one.
        while len(finished) < len(self._in_flight):
            try:
                finished.append(self._finished(self._done.get(timeout=GATHER_S)))
            except queue.Empty:
                break
        rows = [self._in_flight.pop(out.env) for out in finished]
        return self._rows(finished, rows)

    def _advance_into_done(self, i: int, action: np.ndarray, sent_at: float) -> None:
        try:
            self._done.put(self._advance(i, action, sent_at))
        except BaseException as e:  # raised in the acting thread, by step()
            self._done.put(e)

    @staticmethod
    def _finished(out: _Outcome | BaseException) -> _Outcome:
        if isinstance(out, BaseException):
            raise out
        return out

    def _rows(self, outcomes: list[_Outcome], carry: list[dict[str, np.ndarray]]) -> Columns:
        n = len(outcomes)
        envs = np.array([o.env for o in outcomes], dtype=np.int64)
        obs = self.obs[envs]
        next_obs = np.empty_like(obs)
        rewards = np.zeros(n, np.float32)
        terminated = np.zeros(n, bool)
        truncated = np.zeros(n, bool)
        lost = np.zeros(n, bool)
        streams = self.streams[envs].copy()
        for j, out in enumerate(outcomes):
            i = out.env
            if out.result is None:  # the world went away mid-step
                self.connection_losses += 1
                self.reconnects += 1
                lost[j], next_obs[j], truncated[j] = True, obs[j], True
                self.episode_returns[i] = 0.0
                self.streams[i] += len(self.envs)
            else:
                next_obs[j], rewards[j], terminated[j], truncated[j], info = out.result
                self.meter.step(i, info.get("tick"), out.own_s)
                self.episode_returns[i] += rewards[j]
                if terminated[j] or truncated[j]:
                    self.finished_returns.append(float(self.episode_returns[i]))
                    self.episode_returns[i] = 0.0
            if out.reset is not None:
                self.obs[i] = self._begin(i, out.reset, out.ready_at)
            else:
                self.obs[i] = next_obs[j]
                self._ready_at[i] = out.ready_at
        self.stepped = envs
        self.lost = lost
        record: Columns = {
            "obs": obs.astype(np.float32),
            "reward": rewards,
            "terminated": terminated,
            "truncated": truncated,
            "next_obs": next_obs.astype(np.float32),
            "_stream": streams,
        }
        keys = carry[0].keys() if carry else ()
        for k in keys:
            record[k] = carry[0][k] if len(carry) == 1 else np.concatenate([c[k] for c in carry])
        return record

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
        for env in self.envs:
            env.close()
