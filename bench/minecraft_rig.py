"""The real-time rig the decoupling table and the clients sweep both run: a pool of world
servers at real Malmo's 50 ms ticks, a replay server, a TD3 learner sampling from it at full
speed and broadcasting its weights, and the measured window of the env actors beside them.
"""

from __future__ import annotations

import argparse
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Optional

import ray
import torch
from procfs import cpu_seconds

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import EnvActor, Segment
from actors.task import EnvSpec
from actors.transitions import replay_signature
from graft.replay_host.process import ReplayProcess
from learner.td3.builder import make_actor_network, make_td3_learner
from learner.td3.config import TD3Config
from learner.td3.networks import acting_copy
from minecraft.agent.mission_env import ACTION_SPACE, observation_space
from minecraft.malmo.mission import parse_mission
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.pool import ServerPool
from service.core import as_arrays
from service.replay.client import ReplayClient
from service.weights import WeightBroadcaster, WeightSubscriber

TABLE = "minecraft"
MS_PER_TICK = 50
INSERT_EVERY = 32  # transitions per insert
PENDING_INSERTS = 64  # insert batches an actor may queue before acting waits


def bench_mission(seed: int) -> str:
    """The sample mission's observations and handlers in real time, with the small frame
    real Malmo needs (the actors' vectors do not use frames)."""
    return mission_xml(
        width=None, ms_per_tick=MS_PER_TICK, seed=seed, time_limit_ms=None,
        handlers="continuous discrete inventory craft quit",
    )  # fmt: skip


@ray.remote(num_cpus=1, max_concurrency=2)  # type: ignore[call-overload]
class FullSpeedLearner:
    """TD3 sampling from the replay server as fast as it can, publishing weights every
    ``publish_every`` updates. ``nice`` raises its niceness above Ray's default 15."""

    def __init__(
        self, replay: ReplayClient, broadcaster: Any, *, obs_dim: int, td3: TD3Config,
        seed: int, threads: int, nice: int, publish_every: int = 50,
    ) -> None:  # fmt: skip
        self.nice = nice
        torch.set_num_threads(threads)
        box = observation_space(parse_mission(bench_mission(seed)))
        assert box.shape == (obs_dim,)
        self.learner = make_td3_learner(box, ACTION_SPACE, td3, seed)
        self.replay, self.broadcaster = replay, broadcaster
        self.batch_size, self.publish_every = td3.batch_size, publish_every
        self._stop = threading.Event()
        self._window: tuple[float, int] = (time.perf_counter(), 0)
        self.version = 0

    def _publish(self) -> None:
        ref = ray.put(as_arrays(self.learner.policy_state()))
        ray.get(self.broadcaster.publish.remote(self.version, [ref]))
        self.version += 1

    def run(self) -> dict[str, float]:
        """Train until ``stop()``; returns updates and updates/s since ``mark()``."""
        os.nice(self.nice)  # per thread on Linux: this one, and the prefetch thread it starts
        self._publish()  # version 0: the actors switch from random to the network
        stream = self.replay.sample_stream(TABLE, self.batch_size, prefetch=4)
        for batch in stream:
            columns = {k: torch.tensor(v) for k, v in batch.items() if not k.startswith("_")}
            self.learner.update(columns)
            if self.learner.num_updates % self.publish_every == 0:
                self._publish()
            if self._stop.is_set():
                break
        stream.close()
        t0, u0 = self._window
        done = self.learner.num_updates - u0
        return {"updates": float(done), "updates_per_s": done / (time.perf_counter() - t0)}

    def mark(self) -> None:
        """Start the measurement window."""
        self._window = (time.perf_counter(), self.learner.num_updates)

    def stop(self) -> None:
        self._stop.set()


def summary(reports: list[dict[str, Any]], updates_per_s: float) -> dict[str, float]:
    """The table's figures from the actors' reports: ticks skipped, pace, latency, losses."""
    seen = sum(r["perf/ticks_seen"] for r in reports)
    skipped = sum(r["perf/ticks_skipped"] for r in reports)
    n = len(reports)
    return {
        "skipped": skipped / max(seen + skipped, 1),
        "steps_per_s": sum(r["perf/steps_per_s"] for r in reports) / n,
        "ticks_per_s": sum(r["perf/world_ticks_per_s"] for r in reports) / n,
        "p50": max(r["perf/step_latency_ms_p50"] for r in reports),
        "p99": max(r["perf/step_latency_ms_p99"] for r in reports),
        "updates_per_s": updates_per_s,
        "losses": sum(r["net/connection_losses"] for r in reports),
        "insert_wait_s": max(r.get("replay/insert_wait_s", 0.0) for r in reports),
        "versions": min(r.get("policy/versions_adopted", 0) for r in reports),
        "nice": max(r["actor/nice"] for r in reports),
    }


@dataclass
class Rig:
    """What one run's env actors connect to, started by `rig()`."""

    pool: ServerPool
    replay: ReplayClient
    broadcaster: Any  # a WeightBroadcaster actor
    learner: Any  # a FullSpeedLearner actor
    behaviour: GaussianBehaviour
    segment: Segment

    def env_actor(
        self, env: EnvSpec, *, num_envs: int, seed: int, async_envs: bool = False,
        num_cpus: Optional[float] = None,
    ) -> Any:  # fmt: skip
        """An env actor acting with the rig's behaviour and weights, streaming to its replay
        server, at the acting niceness 0; ``num_cpus`` overrides the actor's default."""
        cls = EnvActor if num_cpus is None else EnvActor.options(num_cpus=num_cpus)
        return cls.remote(
            env=env,
            num_envs=num_envs,
            seed=seed,
            replay=self.replay,
            weights=WeightSubscriber(self.broadcaster),
            behaviour=self.behaviour,
            steps_per_insert=max(1, INSERT_EVERY // num_envs),
            nice=0,
            async_envs=async_envs,
        )


@contextmanager
def rig(args: argparse.Namespace, td3: TD3Config, *, clients: int, max_size: int) -> Iterator[Rig]:
    """`clients` real-time world servers, a replay table of `max_size` and the learner."""
    obs_space = observation_space(parse_mission(bench_mission(args.seed)))
    low, high = ACTION_SPACE.low, ACTION_SPACE.high
    network = make_actor_network(obs_space.shape[0], ACTION_SPACE.shape[0], low, high, td3)
    acting = acting_copy(network)
    behaviour = GaussianBehaviour(acting, std=td3.exploration_noise, low=low, high=high)
    table = {
        "name": TABLE, "max_size": max_size,
        "signature": replay_signature(obs_space, behaviour.columns()),
        "rate_limiter": {"kind": "min_size", "min_size": td3.batch_size},  # inserts never wait
    }  # fmt: skip
    # A min_size table never holds inserts back: acting need not wait for any of them.
    segment = Segment(TABLE, steps=10**9, pending_inserts=PENDING_INSERTS)
    with ServerPool(clients, base_port=0, seed=args.seed, ms_per_tick=MS_PER_TICK) as pool:
        with ReplayProcess([table]) as server:
            replay = ReplayClient(server.address)
            broadcaster = WeightBroadcaster.remote()
            learner = FullSpeedLearner.remote(
                replay, broadcaster, obs_dim=obs_space.shape[0], td3=td3, seed=args.seed,
                threads=args.learner_threads, nice=args.learner_nice,
            )  # fmt: skip
            yield Rig(pool, replay, broadcaster, learner, behaviour, segment)


@dataclass(frozen=True)
class Window:
    """One measured window: the actors' reports at its start and end and those their runs
    returned, the learner's updates/s over it, the world servers' CPU seconds in it."""

    before: list[dict[str, Any]]
    after: list[dict[str, Any]]
    final: list[dict[str, Any]]
    updates_per_s: float
    world_cpu_s: float


def measure(rig: Rig, actors: list[Any], *, warmup: float, seconds: float) -> Window:
    """Run the learner and `actors` for `warmup` s, measure `seconds`, then stop and end them."""
    ray.get([a.report.remote() for a in actors])  # constructed, connected: time from here
    training = rig.learner.run.remote()
    runs = [a.run.remote([rig.segment]) for a in actors]
    time.sleep(warmup)
    ray.get([rig.learner.mark.remote(), *(a.restart_meters.remote() for a in actors)])
    before = ray.get([a.report.remote() for a in actors])
    worlds = sum(cpu_seconds(p.pid) for p in rig.pool.procs)
    time.sleep(seconds)
    after = ray.get([a.report.remote() for a in actors])
    worlds = sum(cpu_seconds(p.pid) for p in rig.pool.procs) - worlds
    ray.get(rig.broadcaster.stop.remote())  # as the learner loop ends a run
    final = ray.get(runs)
    ray.get(rig.learner.stop.remote())
    trained = ray.get(training)
    ray.get([a.close.remote() for a in actors])
    for handle in [*actors, rig.learner, rig.broadcaster]:
        ray.kill(handle)
    rig.replay.close()
    return Window(before, after, final, trained["updates_per_s"], worlds)
