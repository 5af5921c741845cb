"""`graft tune`: throughput of a preset's pipeline over a grid of knobs, with simulated actors.

Each grid point is a short run of the real pipeline — the replay server process, env
actors on Ray (stepping `actors.simulated.SimulatedEnv` with the preset's spaces and
behaviour, so they insert the preset's exact transitions), the weight broadcast and a
learner in this process — measured for a fixed time after a warm-up::

    for point in grid:                    # e.g. actors=1,2,4 x td3.batch_size=64,256
        start replay server(s) and actors # the point's config and step cost
        learn for warmup_s, then measure_s: updates, waits, publishes, inserts, CPU
        stop them; row = measure(...); row["bottleneck"] = bottleneck(...)

The learner is the preset's algorithm (`real`), a stand-in costing a fixed time per update
(`cost`), or one that only draws batches (`drain`). Which component saturated first is
decided by `bottleneck` from the measured waits; its docstring states the rule.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import os
import secrets
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray
import torch
from tqdm import tqdm

from actors.env_actor import EnvActor, Segment
from actors.simulated import ENV_ID, busy_wait, simulated_env_kwargs
from actors.task import EnvSpec
from actors.transitions import replay_signature
from learner.loop import to_tensors
from service.core import Weights
from service.replay.client import ReplayClient
from service.replay.sharding import ShardedReplayClient
from service.run.config import TrainConfig, load_preset
from service.run.orchestration.preflight import check_task, local_cpus
from service.run.orchestration.ray_session import connect_ray
from service.run.orchestration.roles import PENDING_INSERTS
from service.run.orchestration.tables import table_spec
from service.run.registry import make_builder
from service.run.replay_host.process import ReplayProcess
from service.run.replay_host.shards import shard_tables
from service.run.validation import ConfigError
from service.weights import BroadcastPublisher

SATURATED = 0.25
"""A side waiting at least this share of the measured time is being held by the other."""
SKIPPED_LIMIT = 0.01
"""Real-time actors skipping more than this share of their ticks cannot keep up."""
LEARNERS = ("real", "cost", "drain")
FILL_TIMEOUT_S = 120.0
"""The longest a point waits for its table to reach the size sampling starts at."""
TUNE_MAX_SIZE = 100_000
"""Replay capacity of a tuning point (a short run never needs more)."""

ALIASES = {
    "actors": "num_actors",
    "envs": "envs_per_actor",
    "publish_interval": "publish_every",
    "slack": "slack_env_steps",
    "replay_shards": "replay.shards",
}
"""Short names of config knobs (`batch_size` is the algorithm section's)."""


@dataclass(frozen=True)
class Costs:
    """What a point's simulated parts cost: the knobs that are not preset fields."""

    learner: str = "real"
    """real (the preset's algorithm), cost (a fixed time per update) or drain (none)."""
    learner_cost_ms: float = 0.0
    """Time per update of the `cost` learner."""
    learner_busy: bool = True
    """The `cost` learner busy-waits (True) or sleeps (False)."""
    step_cost_ms: float = 0.0
    """CPU busy-waited per simulated env step."""
    step_latency_ms: float = 0.0
    """Time slept per simulated env step."""
    actor_steps_per_s: float = 0.0
    """Most env steps per second of one actor (0: as fast as possible)."""
    tick_ms: float = 0.0
    """Real-time mode: each simulated world ticks every tick_ms; skipped ticks are counted."""
    actor_cpus: float = 0.25
    """CPUs Ray reserves for each actor."""
    samples_per_insert: Optional[float] = None
    """Sampled items per inserted item (None: the preset's updates_per_env_step x batch)."""

    def __post_init__(self) -> None:
        if self.learner not in LEARNERS:
            raise ValueError(f"learner={self.learner!r} is unknown; choose from {LEARNERS}")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not value >= 0:
                raise ValueError(f"{f.name}={value} must be >= 0")
        if self.actor_cpus <= 0:
            raise ValueError(f"actor_cpus={self.actor_cpus} must be > 0")
        if self.samples_per_insert is not None and self.samples_per_insert <= 0:
            raise ValueError(f"samples_per_insert={self.samples_per_insert} must be > 0")


COST_KNOBS = {f.name for f in dataclasses.fields(Costs)}


def knob_key(name: str, algorithm: str) -> str:
    """The preset key (or `Costs` field) a knob name stands for."""
    if name == "batch_size":
        return f"{'dqn' if algorithm == 'ddqn' else 'td3'}.batch_size"
    return ALIASES.get(name, name)


def parse_grid(pairs: Sequence[str]) -> dict[str, list[Any]]:
    """`--grid name=v1,v2,...` pairs as {name: [values]} (values parsed as YAML scalars).

    Raises:
        ConfigError: a pair without '=' or without values, or a knob named twice.
    """
    import yaml

    grid: dict[str, list[Any]] = {}
    for pair in pairs:
        name, sep, values = pair.partition("=")
        name = name.strip()
        if not sep or not name or not values.strip():
            raise ConfigError(f"--grid {pair!r}: expected name=v1,v2,..., e.g. actors=1,2,4")
        if name in grid:
            raise ConfigError(f"--grid {name} given twice; list all its values once")
        grid[name] = [yaml.safe_load(v) for v in values.split(",")]
    return grid


@dataclass(frozen=True)
class Point:
    """One grid point: its knob values, the run config and the costs they make."""

    knobs: dict[str, Any]
    config: TrainConfig
    costs: Costs


def plan(
    preset: str,
    grid: dict[str, list[Any]],
    *,
    overrides: dict[str, Any],
    costs: Costs,
    address: str,
) -> list[Point]:
    """Every grid point's config and costs, refused in one line before anything starts.

    Raises:
        ConfigError: an unknown knob, a value the config or the costs refuse, or more
            actor CPUs than a local Ray instance has.
    """
    base = load_preset(preset, **overrides)
    points = []
    for values in itertools.product(*grid.values()):
        knobs = dict(zip(grid, values, strict=True))
        config_overrides, cost_overrides = dict(overrides), {}
        for name, value in knobs.items():
            key = knob_key(name, base.algorithm)
            if key in COST_KNOBS:
                cost_overrides[key] = value
            else:
                config_overrides[key] = value
        try:
            point_costs = dataclasses.replace(costs, **cost_overrides)
        except (ValueError, TypeError) as e:
            raise ConfigError(f"--grid {knobs}: {e}") from None
        batch_key = knob_key("batch_size", base.algorithm)
        section, _, field = batch_key.partition(".")
        batch = config_overrides.get(batch_key, getattr(getattr(base, section), field))
        try:
            config = load_preset(preset, **_tuning_budget(config_overrides, int(batch)))
        except ConfigError as e:
            knobs_known = sorted({*ALIASES, "batch_size", *COST_KNOBS})
            raise ConfigError(f"{e}; tune's own knobs: {', '.join(knobs_known)}") from None
        if address == "local":
            need = config.num_actors * point_costs.actor_cpus
            have = local_cpus()
            if need > have:
                raise ConfigError(
                    f"{config.num_actors} actors x actor_cpus={point_costs.actor_cpus:g} need "
                    f"{need:g} CPUs; the local Ray instance has {have:g}"
                )
        points.append(Point(knobs, config, point_costs))
    return points


def _tuning_budget(overrides: dict[str, Any], batch_size: int) -> dict[str, Any]:
    """A budget no point reaches (a point ends after its measured time), and a table that
    starts sampling at two batches unless `learning_starts` is given."""
    return {"env_steps": 10**12, "learning_starts": 2 * batch_size, **overrides}


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


def _snapshot(learner: TuningLearner, actors: list[Any], servers: list[ReplayProcess],
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


def run_point(
    point: Point, *, warmup_s: float, measure_s: float, address: str, seed: int = 0
) -> dict[str, Any]:
    """One grid point: the pipeline for `warmup_s`, then `measure_s` measured."""
    config, costs = point.config, point.costs
    torch.set_num_threads(1)
    builder = make_builder(config)
    behaviour = builder.make_behaviour(num_actors=config.num_actors)
    env = config.make_env()
    env_kwargs = simulated_env_kwargs(
        env,
        cpu_ms=costs.step_cost_ms,
        latency_ms=costs.step_latency_ms,
        steps_per_s=costs.actor_steps_per_s / config.envs_per_actor,
        tick_ms=costs.tick_ms,
    )
    signature = replay_signature(env.observation_space, behaviour.columns())
    env.close()
    phase = builder.phases()[-1]
    if costs.samples_per_insert is not None and phase.samples_per_insert is not None:
        phase = dataclasses.replace(phase, samples_per_insert=costs.samples_per_insert)
    table = table_spec(
        phase,
        signature=signature,
        max_size=min(config.replay_max_size, TUNE_MAX_SIZE),
        slack_env_steps=config.slack_env_steps,
    )
    host = "127.0.0.1" if address == "local" else "0.0.0.0"
    token = None if address == "local" else secrets.token_urlsafe(24)
    actors: list[Any] = []
    with contextlib.ExitStack() as servers:
        replay = [
            servers.enter_context(ReplayProcess(tables, host=host, token=token))
            for tables in shard_tables([table], config.replay.shards)
        ]
        addresses = [r.address for r in replay]
        if host == "0.0.0.0":
            node = ray.util.get_node_ip_address()
            addresses = [f"{node}:{a.rsplit(':', 1)[1]}" for a in addresses]
        shards = [ReplayClient(a, token=token) for a in addresses]
        client = _replay_client(addresses, token)
        publisher = BroadcastPublisher()
        n = config.num_actors
        segment = Segment(
            phase.name,
            steps=10**12,
            warmup_steps=-(-phase.warmup_steps // n),
            pending_inserts=0 if phase.samples_per_insert is not None else PENDING_INSERTS,
        )
        try:
            for i in range(n):
                # @ray.remote gives the class `.options` at run time; mypy sees the plain class.
                actors.append(
                    EnvActor.options(num_cpus=costs.actor_cpus).remote(  # type: ignore[attr-defined]
                        env=EnvSpec(ENV_ID, env_kwargs),
                        num_envs=config.envs_per_actor,
                        seed=seed * 1000 + i * config.envs_per_actor,
                        replay=_replay_client(addresses, token, home=i),
                        weights=publisher.subscriber(),
                        behaviour=behaviour,
                        steps_per_insert=config.steps_per_insert,
                        nice=0 if costs.tick_ms else None,
                    )
                )
            ray.get([a.report.remote() for a in actors])  # started: time from here
            stream = client.sample_stream(phase.name, builder.batch_size, prefetch=config.prefetch)
            learner = TuningLearner(point, stream=stream, publisher=publisher, builder=builder)
            learner.publish()  # version 0: actors act with it after their warm-up steps
            runs = [a.run.remote([segment]) for a in actors]
            filled_by = time.monotonic() + FILL_TIMEOUT_S
            while learner.counters.updates == 0 and time.monotonic() < filled_by:
                learner.run_until(time.monotonic() + 0.5)  # the table fills to min_size
                _raise_actor_errors(runs)
            learner.run_until(time.monotonic() + warmup_s)
            ray.get([a.restart_meters.remote() for a in actors])
            before = _snapshot(learner, actors, replay, shards, phase.name)
            learner.run_until(time.monotonic() + measure_s)
            after = _snapshot(learner, actors, replay, shards, phase.name)
            _raise_actor_errors(runs)
            publisher.stop()
            stream.close()
        finally:
            for actor in actors:
                ray.kill(actor)
            publisher.close()
            for c in [client, *shards]:
                c.close()
    row = measure(before, after, learner.version)
    row["bottleneck"] = bottleneck(
        learner_wait=row["learner_wait"],
        publish=row["publish_fraction"],
        actor_hold=row["actor_insert_wait"],
        skipped=None if costs.tick_ms == 0 else row["skipped"],
    )
    return {**point.knobs, **row}


def _replay_client(
    addresses: list[str], token: Optional[str], *, home: int = 0
) -> ReplayClient | ShardedReplayClient:
    """One server's client, or a sharded one inserting into shard `home` mod N (as a run's
    actor `home` does: service/run/replay_host/shards.py)."""
    if len(addresses) == 1:
        return ReplayClient(addresses[0], token=token)
    return ShardedReplayClient(addresses, token=token, home=home % len(addresses))


def _raise_actor_errors(runs: list[Any]) -> None:
    """An actor that died during the point raises its error here (not a silent zero)."""
    finished, _ = ray.wait(runs, num_returns=len(runs), timeout=0)
    for ref in finished:
        ray.get(ref)


def sweep(
    points: list[Point],
    *,
    warmup_s: float,
    measure_s: float,
    address: str,
    progress: bool = True,
    on_row: Optional[Callable[[dict[str, Any]], None]] = None,
) -> list[dict[str, Any]]:
    """Runs every point in turn on one Ray instance (started here unless one runs)."""
    check_task(points[0].config)
    started = connect_ray(address)
    rows: list[dict[str, Any]] = []
    try:
        bar = tqdm(points, unit="point", disable=not progress, dynamic_ncols=True)
        for point in bar:
            bar.set_description(" ".join(f"{k}={v}" for k, v in point.knobs.items()))
            row = run_point(point, warmup_s=warmup_s, measure_s=measure_s, address=address)
            rows.append(row)
            bar.set_postfix(
                steps_per_s=f"{row['inserted_per_s']:.0f}",
                updates_per_s=f"{row['learner_updates_per_s']:.0f}",
                bottleneck=row["bottleneck"],
            )
            if on_row is not None:
                on_row(row)
        bar.close()
    finally:
        if started:
            ray.shutdown()
    return rows
