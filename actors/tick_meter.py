"""What an actor reports about real time: the world ticks its environments' observations
skipped, and its own time per step.

An environment whose world runs on its own clock (a real-time Minecraft client) reports
that clock as ``info["tick"]`` from ``reset()`` and ``step()``; a world that advances
``k`` ticks between two observations skipped ``k - 1`` of them. The actor's own time
per step is measured for every environment: from an observation arriving to the next
action leaving (acting, bookkeeping, waiting on replay). Above the world's tick length
the world ticks unobserved.

    meter = TickMeter(num_envs)
    meter.begin(i, info.get("tick"))                   # after env i's reset
    meter.step(i, info.get("tick"), own_s)             # after each of env i's steps
    meter.metrics()["perf/ticks_skipped_fraction"]     # 0.0 when every tick was seen
"""

from __future__ import annotations

import collections
import threading
from typing import Optional

import numpy as np


class TickMeter:
    """Counts seen and skipped ticks per environment and keeps recent step latencies.

    Args:
        num_envs: environments metered side by side (each has its own clock).
        window: step latencies kept for the percentiles.
    """

    def __init__(self, num_envs: int, *, window: int = 1000) -> None:
        self._last: list[Optional[int]] = [None] * num_envs
        self._latencies: collections.deque[float] = collections.deque(maxlen=window)
        self._lock = threading.Lock()  # metrics() may be read from another thread
        self.seen = 0
        self.skipped = 0

    def begin(self, env: int, tick: Optional[int]) -> None:
        """Environment ``env`` started an episode; ``tick`` is its first observation's
        clock (None: the environment reports none). Gaps across episodes do not count."""
        with self._lock:
            self._last[env] = None
            self._observe(env, tick)

    def step(self, env: int, tick: Optional[int], latency_s: float) -> int:
        """One step of environment ``env``; returns the ticks it skipped.

        Args:
            env: which environment stepped.
            tick: the world clock of the new observation, or None (none reported).
            latency_s: the actor's own time before this step's action left.
        """
        with self._lock:
            self._latencies.append(latency_s)
            return self._observe(env, tick)

    def _observe(self, env: int, tick: Optional[int]) -> int:
        if tick is None:
            return 0
        last, skipped = self._last[env], 0
        if last is not None and tick > last:
            skipped = tick - last - 1
            self.skipped += skipped
        self.seen += 1
        self._last[env] = tick
        return skipped

    def restart(self) -> None:
        """Start a new measurement window (the environments' clocks are kept)."""
        with self._lock:
            self.seen = self.skipped = 0
            self._latencies.clear()

    def skipped_fraction(self) -> float:
        """Skipped ticks over all ticks that passed while observing."""
        total = self.seen + self.skipped
        return self.skipped / total if total else 0.0

    def latency_ms(self, q: float) -> float:
        """The ``q``-th percentile of recent step latency in milliseconds (nan before any)."""
        with self._lock:
            latencies = list(self._latencies)
        if not latencies:
            return float("nan")
        return float(np.percentile(latencies, q) * 1000.0)

    def metrics(self) -> dict[str, float]:
        """Namespaced metrics; the tick counts only once an environment reported ticks."""
        with self._lock:
            seen, skipped = self.seen, self.skipped
        out = {
            "perf/step_latency_ms_p50": self.latency_ms(50.0),
            "perf/step_latency_ms_p99": self.latency_ms(99.0),
        }
        if seen:
            out["perf/ticks_seen"] = float(seen)
            out["perf/ticks_skipped"] = float(skipped)
            out["perf/ticks_skipped_fraction"] = skipped / (seen + skipped)
        return out
