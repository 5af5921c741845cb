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
import time
from collections.abc import Callable
from typing import Any, Optional

import ray
import torch
from tqdm import tqdm

from actors.env_actor import Segment
from actors.simulated import ENV_ID, simulated_env_kwargs
from actors.task import EnvSpec
from actors.transitions import replay_signature
from graft.orchestration.assembly import RunParts
from graft.orchestration.kept import ENV_ACTORS, KEPT, env_actor, options_key
from graft.orchestration.preflight import check_task
from graft.orchestration.ray_session import connect_ray
from graft.orchestration.roles import PENDING_INSERTS
from graft.orchestration.tables import table_spec
from graft.registry import make_builder
from graft.replay_host.process import ReplayProcess
from graft.replay_host.shards import shard_tables
from graft.tuning.grid import Point
from graft.tuning.measure import TuningLearner, bottleneck, measure, snapshot
from service.replay.client import ReplayClient
from service.replay.errors import ReplayError
from service.replay.sharding import ShardedReplayClient

FILL_TIMEOUT_S = 120.0
"""The longest a point waits for its table to reach the size sampling starts at."""
ACTOR_END_S = 10.0
"""Seconds a point's actors get to end their runs once it is measured; those that do are
kept for the next point (graft/orchestration/kept.py), the others ended."""
DRAIN_CHECK_S = 0.05
"""How often a finished point, drawing batches for its held actors, checks that they ended."""
TUNE_MAX_SIZE = 100_000
"""Replay capacity of a tuning point (a short run never needs more)."""


def run_point(
    point: Point, *, warmup_s: float, measure_s: float, address: str, seed: int = 0
) -> dict[str, Any]:
    """One grid point: the pipeline for `warmup_s`, then `measure_s` measured."""
    config, costs = point.config, point.costs
    torch.set_num_threads(1)
    builder = make_builder(config)
    behaviour = builder.make_behaviour(num_actors=config.num_actors)
    phase, table, env_kwargs = _point_table(point, builder, behaviour)
    with RunParts(address) as parts:
        replay = [
            parts.enter(ReplayProcess(tables, host=parts.host, token=parts.token))
            for tables in shard_tables([table], config.replay.shards)
        ]
        addresses = [r.address for r in replay]
        if parts.host == "0.0.0.0":
            node_ip = ray.util.get_node_ip_address()
            addresses = [f"{node_ip}:{a.rsplit(':', 1)[1]}" for a in addresses]
        shards = [ReplayClient(a, token=parts.token) for a in addresses]
        client = _replay_client(addresses, parts.token)
        for c in [client, *shards]:
            parts.on_exit(c.close)
        publisher = parts.broadcaster()
        options = {"num_cpus": costs.actor_cpus, "max_concurrency": 2}
        actors: list[Any] = []
        parts.on_exit(lambda: [ray.kill(actor) for actor in actors])  # those not handed on
        for i in range(config.num_actors):
            arguments = dict(
                env=EnvSpec(ENV_ID, env_kwargs),
                num_envs=config.envs_per_actor,
                seed=seed * 1000 + i * config.envs_per_actor,
                replay=_replay_client(addresses, parts.token, home=i),
                weights=publisher.subscriber(),
                behaviour=behaviour,
                steps_per_insert=config.steps_per_insert,
                nice=0 if costs.tick_ms else None,
            )
            actors.append(env_actor(options, arguments))
        ray.get([a.report.remote() for a in actors])  # started: time from here
        stream = client.sample_stream(phase.name, builder.batch_size, prefetch=config.prefetch)
        learner = TuningLearner(point, stream=stream, publisher=publisher, builder=builder)
        runs = _learn_point(learner, actors, phase, warmup_s=warmup_s)
        before = snapshot(learner, actors, replay, shards, phase.name)
        learner.run_until(time.monotonic() + measure_s)
        after = snapshot(learner, actors, replay, shards, phase.name)
        _raise_actor_errors(runs)
        publisher.stop()
        # Stopped, each actor ends its run: those that did go to the next point.
        ended = _drain_until_ended(stream, runs, ACTOR_END_S)
        stream.close()
        mine = list(zip(actors, runs, strict=True))
        KEPT.keep(ENV_ACTORS, options_key(options), *(a for a, r in mine if r.hex() in ended))
        actors[:] = [a for a, r in mine if r.hex() not in ended]
        parts.keep = True
    row = measure(before, after, learner.version)
    row["bottleneck"] = bottleneck(
        learner_wait=row["learner_wait"],
        publish=row["publish_fraction"],
        actor_hold=row["actor_insert_wait"],
        skipped=None if costs.tick_ms == 0 else row["skipped"],
    )
    return {**point.knobs, **row}


def _point_table(point: Point, builder: Any, behaviour: Any) -> tuple[Any, dict[str, Any], Any]:
    """A point's phase (its samples-per-insert knob applied), the table spec it fills and
    the simulated environment's arguments (the preset's spaces, the point's step costs)."""
    config, costs = point.config, point.costs
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
    return phase, table, env_kwargs


def _learn_point(
    learner: TuningLearner, actors: list[Any], phase: Any, *, warmup_s: float
) -> list[Any]:
    """Starts the actors' runs, learns until the table has filled to its minimum size and
    then for `warmup_s`; returns the runs, the actors' meters restarted."""
    n = len(actors)
    segment = Segment(
        phase.name,
        steps=10**12,
        warmup_steps=-(-phase.warmup_steps // n),
        pending_inserts=0 if phase.samples_per_insert is not None else PENDING_INSERTS,
    )
    learner.publish()  # version 0: actors act with it after their warm-up steps
    runs = [a.run.remote([segment]) for a in actors]
    filled_by = time.monotonic() + FILL_TIMEOUT_S
    while learner.counters.updates == 0 and time.monotonic() < filled_by:
        learner.run_until(time.monotonic() + 0.5)  # the table fills to min_size
        _raise_actor_errors(runs)
    learner.run_until(time.monotonic() + warmup_s)
    ray.get([a.restart_meters.remote() for a in actors])
    return runs


def _replay_client(
    addresses: list[str], token: Optional[str], *, home: int = 0
) -> ReplayClient | ShardedReplayClient:
    """One server's client, or a sharded one inserting into shard `home` mod N (as a run's
    actor `home` does: graft/replay_host/shards.py)."""
    if len(addresses) == 1:
        return ReplayClient(addresses[0], token=token)
    return ShardedReplayClient(addresses, token=token, home=home % len(addresses))


def _drain_until_ended(stream: Any, runs: list[Any], limit_s: float) -> set[str]:
    """The runs (by ref) that ended within `limit_s`, while batches are sampled and dropped:
    an actor whose insert the table's rate limiter holds ends its run only once sampling
    admits that insert (a slow learner's table, or a high samples-per-insert ratio held
    every actor until the limit, and they were ended instead of kept). A table that went
    away meanwhile admits nothing more: the runs then only get the rest of `limit_s`."""
    deadline = time.monotonic() + limit_s
    while True:
        ready, _ = ray.wait(runs, num_returns=len(runs), timeout=0)
        if len(ready) == len(runs) or time.monotonic() >= deadline:
            return {r.hex() for r in ready}
        try:
            _draw_for(stream, min(DRAIN_CHECK_S, deadline - time.monotonic()))
        except (StopIteration, ReplayError):  # the measured window stands; the actors may not end
            left = max(deadline - time.monotonic(), 0.0)
            return {r.hex() for r in ray.wait(runs, num_returns=len(runs), timeout=left)[0]}


def _draw_for(stream: Any, seconds: float) -> None:
    """Draws batches from `stream`, and drops them, for `seconds`."""
    until = time.monotonic() + seconds
    while (left := until - time.monotonic()) > 0:
        with contextlib.suppress(TimeoutError):
            stream.next_within(left)


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
