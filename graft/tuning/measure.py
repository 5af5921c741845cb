"""What one tuning point measures: the learner that draws (and learns from) batches, each
part's counters, the measured window's figures and the component that saturated first."""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray

from actors.simulated import busy_wait
from graft.replay_host.process import ReplayProcess
from graft.tuning.grid import Point
from learner.loop import to_tensors
from service.core import Weights
from service.replay.client import ReplayClient
from service.weights import BroadcastPublisher

SATURATED = 0.25
"""A side waiting at least this share of the measured time is being held by the other."""
SKIPPED_LIMIT = 0.01
"""Real-time actors skipping more than this share of their ticks cannot keep up."""


def bottleneck(
    *, learner_wait: float, publish: float, actor_hold: float, skipped: Optional[float]
) -> str:
    """Which component saturated first, from the shares of the measured time each side
    waited (the rule `graft tune` prints):

    1. the learner spends >= SATURATED of its time publishing -> ``broadcast``;
    2. real-time actors skip > SKIPPED_LIMIT of their ticks -> ``actors`` (they cannot
       keep up with their worlds);
    3. the learner rarely waits for batches (< SATURATED) while actors wait on inserts
       (>= SATURATED) -> ``learner`` (the rate limiter holds actors for it);
    4. the learner waits, actors do not -> ``actors`` (they cannot fill the table);
    5. both wait -> ``replay`` (the table's rate limiter, or the server, holds both);
    6. neither waits -> ``none`` (balanced: both sides busy).
    """
    if publish >= SATURATED:
        return "broadcast"
    if skipped is not None and skipped > SKIPPED_LIMIT:
        return "actors"
    learner_waits, actors_wait = learner_wait >= SATURATED, actor_hold >= SATURATED
    if actors_wait and not learner_waits:
        return "learner"
    if learner_waits and not actors_wait:
        return "actors"
    return "replay" if learner_waits else "none"


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system) process `pid` has used (nan where /proc is missing)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _machine_busy_s() -> float:
    """CPU seconds every core of this machine has been busy (nan without /proc/stat)."""
    try:
        first = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return float("nan")
    ticks = [int(v) for v in first]
    idle = ticks[3] + ticks[4]  # idle + iowait
    return (sum(ticks[:8]) - idle) / os.sysconf("SC_CLK_TCK")


@dataclass
class LearnerCounters:
    """What the tuning learner counts (seconds and items)."""

    updates: int = 0
    wait_s: float = 0.0
    update_s: float = 0.0
    publish_s: float = 0.0
    publishes: int = 0
    lag_sum: float = 0.0
    lag_rows: int = 0
    cpu_s: float = 0.0


class TuningLearner:
    """Draws batches from one table and learns (or pretends to), publishing weights."""

    def __init__(
        self, point: Point, *, stream: Any, publisher: BroadcastPublisher, builder: Any
    ) -> None:
        self.costs = point.costs
        self.stream, self.publisher = stream, publisher
        self.publish_every = point.config.publish_every
        self.phase = builder.phases()[-1]
        self.algorithm = builder.make_learner()
        self._weights: Weights = self.algorithm.policy_state()
        self.version = 0
        self.counters = LearnerCounters()

    def _update(self, batch: dict[str, np.ndarray]) -> None:
        if self.costs.learner == "real":
            self.phase.step(self.algorithm, to_tensors(batch))
        elif self.costs.learner == "cost":
            seconds = self.costs.learner_cost_ms / 1000
            busy_wait(seconds) if self.costs.learner_busy else time.sleep(seconds)

    def publish(self) -> None:
        t = time.perf_counter()
        weights = self.algorithm.policy_state() if self.costs.learner == "real" else self._weights
        self.publisher.publish(self.version, weights)
        self.counters.publish_s += time.perf_counter() - t
        self.counters.publishes += 1

    def run_until(self, deadline: float) -> None:
        """Learns until `time.monotonic()` passes `deadline`."""
        c = self.counters
        while (remaining := deadline - time.monotonic()) > 0:
            t = time.perf_counter()
            try:
                batch = self.stream.next_within(min(remaining, 0.5))
            except TimeoutError:
                c.wait_s += time.perf_counter() - t
                continue
            c.wait_s += time.perf_counter() - t
            versions = batch["policy_version"]
            acted = versions[versions >= 0]  # -1: the warm-up policy, no weights
            c.lag_sum += float(np.sum(self.version - acted))
            c.lag_rows += len(acted)
            t = time.perf_counter()
            self._update(batch)
            c.update_s += time.perf_counter() - t
            c.updates += 1
            if c.updates % self.publish_every == 0:
                self.version += 1
                self.publish()
        c.cpu_s = time.process_time()


def snapshot(learner: TuningLearner, actors: list[Any], servers: list[ReplayProcess],
              clients: list[ReplayClient], table: str) -> dict[str, Any]:  # fmt: skip
    """Counters of every part at one moment; per replay shard, its inserts and CPU."""
    reports = ray.get([a.report.remote() for a in actors])
    inserts = [next(t.inserts for t in c.info() if t.name == table) for c in clients]
    return {
        "t": time.monotonic(),
        "learner": dataclasses.replace(learner.counters, cpu_s=time.process_time()),
        "actors": reports,
        "inserts": inserts,
        "replay_cpu_s": [_cpu_s(s.process.pid) for s in servers],
        "machine_cpu_s": _machine_busy_s(),
    }


def measure(before: dict[str, Any], after: dict[str, Any], version: int) -> dict[str, Any]:
    """The measured window's figures, from snapshots at its start and end."""
    wall = after["t"] - before["t"]
    lb, la = before["learner"], after["learner"]
    actors = list(zip(before["actors"], after["actors"], strict=True))

    def actor_sum(key: str) -> float:
        return sum(a[key] - b[key] for b, a in actors)

    calls = actor_sum("replay/insert_calls")
    fastest = min(a["replay/fastest_insert_s"] for _, a in actors)
    network_s = calls * fastest if calls else 0.0
    publishes = la.publishes - lb.publishes
    shard_inserted = [
        (a - b) / wall for b, a in zip(before["inserts"], after["inserts"], strict=True)
    ]
    shard_cpu = [
        (a - b) / wall for b, a in zip(before["replay_cpu_s"], after["replay_cpu_s"], strict=True)
    ]
    row: dict[str, Any] = {
        "env_steps_per_s": actor_sum("actor/env_steps") / wall,
        "inserted_per_s": sum(shard_inserted),
        "actor_insert_wait": actor_sum("replay/insert_wait_s") / wall / len(actors),
        "insert_network_s_per_s": network_s / wall / len(actors),
        "insert_limiter_s_per_s": max(actor_sum("replay/insert_call_s") - network_s, 0.0)
        / wall
        / len(actors),
        "learner_updates_per_s": (la.updates - lb.updates) / wall,
        "learner_wait": (la.wait_s - lb.wait_s) / wall,
        "publish_ms": 1000 * (la.publish_s - lb.publish_s) / publishes if publishes else 0.0,
        "publish_fraction": (la.publish_s - lb.publish_s) / wall,
        "policy_lag": (la.lag_sum - lb.lag_sum) / max(la.lag_rows - lb.lag_rows, 1),
        "actor_version_lag": max(version - a["policy/version"] for _, a in actors),
        "cpu_learner": (la.cpu_s - lb.cpu_s) / wall,
        "cpu_replay": sum(shard_cpu),
        "cpu_actors": actor_sum("perf/process_cpu_s") / wall,
        "cpu_machine": (after["machine_cpu_s"] - before["machine_cpu_s"]) / wall,
    }
    seen = sum(a.get("perf/ticks_seen", 0.0) for _, a in actors)
    skipped = sum(a.get("perf/ticks_skipped", 0.0) for _, a in actors)
    row["skipped"] = skipped / (seen + skipped) if seen else float("nan")
    # Per replay shard (one figure per shard, '/'-separated): whether the actors' inserts
    # spread over the shards, and which server's CPU saturates.
    row["shard_inserted_per_s"] = " / ".join(f"{v:.0f}" for v in shard_inserted)
    row["shard_cpu_replay"] = " / ".join(f"{v:.2f}" for v in shard_cpu)
    return row
