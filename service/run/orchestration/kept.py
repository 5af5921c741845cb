"""The helpers a driver keeps between its runs on one Ray instance: the weight broadcaster
and the evaluator.

Neither holds anything of a run once it ends: the broadcaster starts over
(`WeightBroadcaster.reset`), the evaluator takes the next run's environment, behaviour and
seed (`Evaluator.reset`). A driver that trains run after run on a Ray instance it leaves
running (`graft.train` in a loop or a notebook, a sweep's runs, the tests) hands them from
one run to the next instead of starting two worker processes a run, each about 0.6-0.8 s
of CPU (`import ray` alone is 0.45 s) and as long before the run can publish or evaluate.

One that no run takes within `KEEP_S` is ended, so the CPU share an evaluator holds comes
back; a run that needs an evaluator of other Ray options ends the kept one at once. A run
that started its own Ray instance ends both with it, as before.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Optional

import ray

KEEP_S = 10.0
"""How long a finished run's helpers wait for the next run before they are ended."""
BROADCASTER, EVALUATOR = "broadcaster", "evaluator"
"""The roles kept, one actor each."""


@dataclass(frozen=True)
class _Kept:
    instance: tuple[str, str]
    key: str
    actor: Any
    timer: threading.Timer


class KeptActors:
    """At most one idle actor per role, with the key it fits (e.g. its Ray options), each
    ended after `keep_s` unless a run takes it."""

    def __init__(self, keep_s: float = KEEP_S) -> None:
        self.keep_s = keep_s
        """Seconds an untaken actor is kept."""
        self._lock = threading.Lock()
        self._kept: dict[str, _Kept] = {}

    def take(self, role: str, key: str) -> Optional[Any]:
        """The actor kept for `role` if it was kept under `key` on this Ray instance, else
        None (one kept under another key is ended now)."""
        with self._lock:
            kept = self._kept.pop(role, None)
        if kept is None:
            return None
        kept.timer.cancel()
        if kept.instance != _instance():  # its Ray instance (and the actor with it) is gone
            return None
        if kept.key == key:
            return kept.actor
        ray.kill(kept.actor)
        return None

    def held(self, role: str) -> Optional[Any]:
        """The actor kept for `role` now, if any (it stays kept)."""
        with self._lock:
            kept = self._kept.get(role)
        return None if kept is None else kept.actor

    def keep(self, role: str, key: str, actor: Any) -> None:
        """Holds `actor`, which fits runs asking for `key`, for the next `take` of `role`."""
        timer = threading.Timer(self.keep_s, self._expire, args=(role, actor))
        timer.daemon = True
        with self._lock:
            previous = self._kept.pop(role, None)
            self._kept[role] = _Kept(_instance(), key, actor, timer)
        timer.start()
        if previous is not None:
            previous.timer.cancel()
            _end(previous)

    def _expire(self, role: str, actor: Any) -> None:
        with self._lock:
            kept = self._kept.get(role)
            if kept is None or kept.actor is not actor:  # taken, or replaced, meanwhile
                return
            del self._kept[role]
        _end(kept)


def _instance() -> tuple[str, str]:
    """This driver's Ray instance and job: an actor outlives neither."""
    context = ray.get_runtime_context()
    return str(context.gcs_address), context.get_job_id()


def _end(kept: _Kept) -> None:
    if ray.is_initialized() and _instance() == kept.instance:
        ray.kill(kept.actor)


KEPT = KeptActors()
"""This driver's kept helpers."""
