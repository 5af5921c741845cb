"""The helpers a driver keeps between its runs on one Ray instance: the weight broadcaster,
the evaluator and the environment actors.

None holds anything of a run once it ends: the broadcaster starts over
(`WeightBroadcaster.reset`), the evaluator takes the next run's environment, behaviour and
seed (`Evaluator.reset`), and an environment actor closes its environments and writer and
sets up as a new one would (`EnvActor.reset`). A driver that trains run after run on a Ray
instance it leaves running (`graft.train` in a loop or a notebook, a sweep's runs, the
tests) hands them from one run to the next instead of starting a worker process for each,
about 0.5-0.8 s of CPU apiece (`import ray` alone is 0.45 s) and as long before the run
can act, publish or evaluate.

One that no run takes within `KEEP_S` is ended, so the CPU share it holds comes back; a
run that needs one of other Ray options ends the kept ones at once. A run that started its
own Ray instance ends them with it, as before. A module a kept actor imported stays
imported, as in any Ray worker Ray reuses: an environment edited between two runs in one
session is loaded afresh only by new actors (wait `KEEP_S`, or start Ray again).
"""

from __future__ import annotations

import gc
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Optional

import ray

from actors.env_actor import EnvActor

KEEP_S = 10.0
"""How long a finished run's helpers wait for the next run before they are ended."""
BROADCASTER, EVALUATOR, ENV_ACTORS, BUDGET = "broadcaster", "evaluator", "env actors", "budget"
"""The roles kept: one actor each, and a run's environment actors."""


@dataclass(frozen=True)
class _Kept:
    instance: tuple[str, str]
    key: str
    actors: list[Any]
    timer: threading.Timer


class KeptActors:
    """The idle actors of each role, with the key they fit (e.g. their Ray options), ended
    after `keep_s` unless runs take them."""

    def __init__(self, keep_s: float = KEEP_S) -> None:
        self.keep_s = keep_s
        """Seconds untaken actors are kept."""
        self._lock = threading.Lock()
        self._kept: dict[str, _Kept] = {}

    def take(self, role: str, key: str) -> Optional[Any]:
        """An actor kept for `role` if it was kept under `key` on this Ray instance, else
        None (those kept under another key are ended now)."""
        with self._lock:
            kept = self._kept.get(role)
            if kept is None:
                return None
            if kept.instance == _instance() and kept.key == key:
                actor = kept.actors.pop()
                if kept.actors:
                    return actor
                del self._kept[role]
                kept.timer.cancel()
                return actor
            del self._kept[role]
        kept.timer.cancel()
        _end(kept)
        return None

    def held(self, role: str) -> list[Any]:
        """The actors kept for `role` now (they stay kept)."""
        with self._lock:
            kept = self._kept.get(role)
        return [] if kept is None else list(kept.actors)

    def keep(self, role: str, key: str, *actors: Any) -> None:
        """Holds `actors`, which fit runs asking for `key`, for the next `take`s of `role`
        (in place of any kept before)."""
        if not actors:
            return
        idle = list(actors)
        timer = threading.Timer(self.keep_s, self._expire, args=(role, idle))
        timer.daemon = True
        with self._lock:
            previous = self._kept.pop(role, None)
            self._kept[role] = _Kept(_instance(), key, idle, timer)
        timer.start()
        if previous is not None:
            previous.timer.cancel()
            _end(previous)

    def _expire(self, role: str, idle: list[Any]) -> None:
        with self._lock:
            kept = self._kept.get(role)
            if kept is None or kept.actors is not idle:  # all taken, or replaced, meanwhile
                return
            del self._kept[role]
        _end(kept)
        if ray.is_initialized() and ray.get_runtime_context().worker.mode == ray.WORKER_MODE:
            # The ended actors' handles, and objects of the finished runs, may still sit in
            # reference cycles (a run's parts refer to each other). A Ray worker that ran
            # a run as a task (`graft experiment`'s seeds) then idles and allocates
            # nothing, so Python's cycle collector never runs there; and Ray never ends a
            # worker that still holds references it owns: each such worker stayed, with
            # torch loaded, for the cluster's life. Collected now, it ends a second later.
            # (A driver goes on allocating, and a collection there costs 0.1 s or more.)
            gc.collect()


def take_or_start(
    role: str, key: str, start: Callable[[], Any], reset: Callable[[Any], Any]
) -> Any:
    """An actor of `role` kept under `key`, set up for this run by `reset(actor)` (an
    ObjectRef, waited for: calls to a threaded actor may overtake one another), else a
    new one from `start()`: also in place of one that ended while kept or whose reset
    failed (a new actor then fails, or not, as it always would)."""
    kept = KEPT.take(role, key)
    if kept is not None:
        try:
            ray.get(reset(kept))
            return kept
        except Exception:  # noqa: BLE001 - whatever went wrong, a new actor takes its place
            ray.kill(kept)
    return start()


def options_key(options: Mapping[str, Any]) -> str:
    """The key an actor of Ray `options` is kept under: runs asking for the same take it."""
    return repr(sorted(options.items()))


def env_actor(
    options: Mapping[str, Any], arguments: Mapping[str, Any], *, kept: bool = True
) -> Any:
    """An environment actor of Ray `options`, set up from `EnvActor`'s `arguments`: one kept
    under the same options, reset, else (and always without `kept`) a new one."""

    def start() -> Any:
        # @ray.remote gives the class `.options` at run time; mypy sees the plain class.
        return EnvActor.options(**options).remote(**arguments)  # type: ignore[attr-defined]

    if not kept:
        return start()
    return take_or_start(
        ENV_ACTORS, options_key(options), start, lambda actor: actor.reset.remote(**arguments)
    )


def _instance() -> tuple[str, str]:
    """This driver's Ray instance and job: an actor outlives neither."""
    context = ray.get_runtime_context()
    return str(context.gcs_address), context.get_job_id()


def _end(kept: _Kept) -> None:
    if ray.is_initialized() and _instance() == kept.instance:
        for actor in kept.actors:
            ray.kill(actor)


KEPT = KeptActors()
"""This driver's kept helpers."""
