"""What a Minecraft actor reports about real time: ticks its observations skipped (from
``TotalTime`` between consecutive observations) and its own step latency.

    meter = TickMeter()
    t0 = time.perf_counter()
    r = client.step(cmd)
    meter.observe(r.info["TotalTime"], time.perf_counter() - t0)
    meter.skipped_fraction()   # 0.0 when every tick was seen

A world advancing ``k`` ticks between two observations skipped ``k - 1`` of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np


@dataclass
class TickMeter:
    """Counts seen and skipped ticks and keeps recent step latencies (seconds)."""

    window: int = 1000
    seen: int = 0
    skipped: int = 0
    _last: Optional[int] = None
    _latencies: list[float] = field(default_factory=list)

    def observe(self, total_time: int, latency: Optional[float] = None) -> int:
        """Record one observation's ``TotalTime``; returns ticks skipped since the last.

        A ``TotalTime`` that goes backwards (a new episode) restarts the count.
        """
        skipped = 0
        if self._last is not None and total_time > self._last:
            skipped = total_time - self._last - 1
            self.skipped += skipped
        self.seen += 1
        self._last = total_time
        if latency is not None:
            self._latencies.append(latency)
            if len(self._latencies) > self.window:
                del self._latencies[: len(self._latencies) - self.window]
        return skipped

    def reset_episode(self) -> None:
        """Forget the last ``TotalTime`` (the next observation starts a new episode)."""
        self._last = None

    def skipped_fraction(self) -> float:
        """Skipped ticks over all ticks that passed while observing."""
        total = self.seen + self.skipped
        return self.skipped / total if total else 0.0

    def latency_ms(self, q: float = 50.0) -> float:
        """A percentile of recent step latency, in milliseconds (nan before any step)."""
        if not self._latencies:
            return float("nan")
        return float(np.percentile(self._latencies, q) * 1000.0)

    def metrics(self) -> dict[str, float]:
        """Namespaced metrics for the actor's report."""
        return {
            "perf/ticks_skipped_fraction": self.skipped_fraction(),
            "perf/ticks_skipped": float(self.skipped),
            "perf/step_latency_ms_p50": self.latency_ms(50.0),
            "perf/step_latency_ms_p99": self.latency_ms(99.0),
        }
