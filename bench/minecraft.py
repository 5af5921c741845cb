"""Minecraft benchmarks: world server ticks per second, and the decoupling table.

1. Ticks per second of one simulated world server in synchronous mode (ideal timing),
   through the MalmoEnv protocol, without and with rendering. The server runs in its own process
   (``minecraft serve``), the client is graft's ``MalmoClient``; each step advances
   exactly one tick and returns the observations of the sample obtain-diamond mission
   (full stats, 15×15×15 grid, inventory, entities, ray).
2. The decoupling table: 4 real-time clients (a pool of 4 world servers at 50 ms ticks,
   real Malmo's timing)
   on the same 2 cores as a TD3 learner, as graft runs them (its env actors, each
   stepping a Minecraft mission environment and streaming to the replay server, a learner
   sampling from it at full speed, weights broadcast) beside the paper's naive loop
   (``naive_loop.py``: each client trains its own TD3 between two steps). Reported: the
   fraction of world ticks the clients never observed (``TotalTime`` gaps).

    python bench/minecraft.py                       # both parts, about 3 minutes
    python bench/minecraft.py --part decoupling [--warmup 20 --measure 40 --seed 1]
"""

from __future__ import annotations

import argparse
import os
import re
import threading
import time
from typing import Any

import ray
import torch
from naive_loop import NaiveLoop  # bench/, beside this script (Ray workers import it too)

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import EnvActor, Segment
from actors.minecraft.agent.mission_env import ACTION_SPACE, ENV_ID, observation_space
from actors.minecraft.malmo.client import MalmoClient
from actors.minecraft.malmo.mission import parse_mission
from actors.minecraft.malmo.mission_xml import mission_xml
from actors.minecraft.sim.pool import ServerPool
from actors.minecraft.sim.timing import IDEAL
from actors.task import EnvSpec
from actors.transitions import replay_signature
from learner.td3.builder import make_actor_network, make_td3_learner
from learner.td3.config import TD3Config
from service.replay.client import ReplayClient
from service.run.replay_process import ReplayProcess
from service.weights import WeightBroadcaster, WeightSubscriber


def ticks_per_second(
    port: int, *, size: int | None, ticks: int, seed: int, full: bool = True
) -> float:
    """Synchronous steps (= ticks) per second over ``ticks`` steps of a wandering walk.

    ``full`` uses the sample mission's observations (15×15×15 grid, inventory, entities,
    ray, stats); otherwise only ObservationFromFullStats.
    """
    client = MalmoClient("127.0.0.1", port, synchronous=True, seed=seed)
    obs = "stats inventory ray entities" if full else "stats"
    xml = mission_xml(
        width=size, height=size, time_limit_ms=None, grid_radius=7 if full else 0,
        observations=obs,
    )  # fmt: skip
    if size is None:  # the simulator's own cost: no frame (only ideal timing takes that)
        xml = re.sub(r"<VideoProducer.*?</VideoProducer>", "", xml, flags=re.DOTALL)
    client.init(xml)
    client.reset()
    commands = ["move 1\njump 1", "turn 0.5", "move 1\nattack 1", "turn -0.3\nattack 0"]
    for i in range(50):  # warm-up
        client.step(commands[i % 4])
    t0 = time.perf_counter()
    first = last = None
    for i in range(ticks):
        r = client.step(commands[(i // 25) % 4])
        if r.done:
            client.reset()
            continue
        last = r.info["TotalTime"]
        first = last if first is None else first
    elapsed = time.perf_counter() - t0
    client.close()
    return ticks / elapsed


def ticks_table(args: argparse.Namespace) -> None:
    """Part 1: print ticks per second of one server, synchronous."""
    # Ideal timing: this measures the simulator's ticks, which real Malmo's loading and
    # frame pacing would only hide (and a mission without a frame needs it).
    with ServerPool(1, base_port=0, seed=args.seed, timing=IDEAL) as pool:
        port = pool.ports[0]
        light = ticks_per_second(port, size=None, ticks=args.ticks, seed=args.seed, full=False)
        plain = ticks_per_second(port, size=None, ticks=args.ticks, seed=args.seed)
        drawn = ticks_per_second(port, size=args.size, ticks=args.render_ticks, seed=args.seed)
    print("| one world server, synchronous, through MalmoEnv | ticks/s |")
    print("|---|---|")
    print(f"| no rendering, full stats only (target >= 2000) | {light:,.0f} |")
    print(f"| no rendering, + 15x15x15 grid, inventory, entities, ray | {plain:,.0f} |")
    print(f"| rendering {args.size}x{args.size} RGB, + all observations | {drawn:,.0f} |")


# ------------------------------------------------------------------ decoupling table
TABLE = "minecraft"
CLIENTS = 4
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
        ref = ray.put(self.learner.policy_state())
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


def _summary(reports: list[dict[str, Any]], updates_per_s: float) -> dict[str, float]:
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


def env_kwargs(port: int, seed: int, episode_steps: int) -> dict[str, Any]:
    """One client's mission environment: real time, its own world seed, and an episode
    limit on the actor's side (gymnasium's ``max_episode_steps``)."""
    return {
        "address": f"127.0.0.1:{port}",
        "mission_xml": bench_mission(seed),
        "world_seed": seed,
        "max_episode_steps": episode_steps,
    }


def decoupled(args: argparse.Namespace, td3: TD3Config) -> dict[str, float]:
    """graft: 4 env actors stream to the replay server; a learner trains at full speed."""
    obs_space = observation_space(parse_mission(bench_mission(args.seed)))
    low, high = ACTION_SPACE.low, ACTION_SPACE.high
    network = make_actor_network(obs_space.shape[0], ACTION_SPACE.shape[0], low, high, td3)
    behaviour = GaussianBehaviour(network, std=td3.exploration_noise, low=low, high=high)
    table = {
        "name": TABLE, "max_size": 100_000,
        "signature": replay_signature(obs_space, behaviour.columns()),
        "rate_limiter": {"kind": "min_size", "min_size": td3.batch_size},  # inserts never wait
    }  # fmt: skip
    # A min_size table never holds inserts back: acting need not wait for any of them.
    segment = Segment(TABLE, steps=10**9, pending_inserts=PENDING_INSERTS)
    with ServerPool(CLIENTS, base_port=0, seed=args.seed, ms_per_tick=MS_PER_TICK) as pool:
        with ReplayProcess([table]) as server:
            replay = ReplayClient(server.address)
            broadcaster = WeightBroadcaster.remote()
            learner = FullSpeedLearner.remote(
                replay, broadcaster, obs_dim=obs_space.shape[0], td3=td3, seed=args.seed,
                threads=args.learner_threads, nice=args.learner_nice,
            )  # fmt: skip
            actors = [
                EnvActor.remote(
                    env=EnvSpec(ENV_ID, env_kwargs(port, args.seed + i, args.episode_steps)),
                    num_envs=1,
                    seed=args.seed + i,
                    replay=replay,
                    weights=WeightSubscriber(broadcaster),
                    behaviour=behaviour,
                    steps_per_insert=INSERT_EVERY,
                    nice=0,
                )  # fmt: skip
                for i, port in enumerate(pool.ports)
            ]
            ray.get([a.report.remote() for a in actors])  # constructed, connected: time from here
            training = learner.run.remote()
            runs = [a.run.remote([segment]) for a in actors]
            time.sleep(args.warmup)
            ray.get([learner.mark.remote(), *(a.restart_meters.remote() for a in actors)])
            time.sleep(args.measure)
            ray.get(broadcaster.stop.remote())  # as the learner loop ends a run
            reports = ray.get(runs)
            ray.get(learner.stop.remote())
            trained = ray.get(training)
            ray.get([a.close.remote() for a in actors])
            for handle in [*actors, learner, broadcaster]:
                ray.kill(handle)
            replay.close()
    return _summary(reports, trained["updates_per_s"])


def naive(args: argparse.Namespace, td3: TD3Config) -> dict[str, float]:
    """The paper's loop: each client trains its own TD3 between two steps."""
    # Two calls at once: report() answers while run() acts (Ray's stubs know task options only).
    remote_loop = ray.remote(num_cpus=0.25, max_concurrency=2)(NaiveLoop)  # type: ignore[call-overload]
    with ServerPool(CLIENTS, base_port=0, seed=args.seed, ms_per_tick=MS_PER_TICK) as pool:
        loops = [
            remote_loop.remote(
                env_id=ENV_ID,
                env_kwargs=env_kwargs(port, args.seed + i, args.episode_steps),
                td3=td3,
                seed=args.seed + i,
                updates_per_step=args.naive_updates,
                learning_starts=td3.batch_size,
                nice=0,
            )  # fmt: skip
            for i, port in enumerate(pool.ports)
        ]
        ray.get([c.report.remote() for c in loops])  # constructed, connected: time from here
        total = args.warmup + args.measure
        runs = [c.run.remote(duration_s=total, measure_after_s=args.warmup) for c in loops]
        time.sleep(args.warmup)
        before = sum(ray.get(c.report.remote())["learner/inline_updates"] for c in loops)
        reports = ray.get(runs)
        ray.get([c.close.remote() for c in loops])
        for c in loops:
            ray.kill(c)
    after = sum(r["learner/inline_updates"] for r in reports)
    return _summary(reports, (after - before) / reports[0]["perf/measure_s"])


def updates_alone(obs_dim: int, td3: TD3Config, *, threads: int, seconds: float = 8.0) -> float:
    """Reference: TD3 updates/s in this process on one in-memory batch, nothing else running."""
    torch.set_num_threads(threads)
    box = observation_space(parse_mission(bench_mission(0)))
    learner = make_td3_learner(box, ACTION_SPACE, td3, seed=0)
    b = td3.batch_size
    batch = {
        "obs": torch.rand(b, obs_dim), "next_obs": torch.rand(b, obs_dim),
        "action": torch.rand(b, ACTION_SPACE.shape[0]) * 2 - 1, "reward": torch.rand(b),
        "terminated": torch.zeros(b, dtype=torch.bool),
    }  # fmt: skip
    learner.update(batch)
    start, n = time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        learner.update(batch)
        n += 1
    return n / (time.perf_counter() - start)


def decoupling_table(args: argparse.Namespace) -> None:
    """Part 2: print the decoupling table."""
    td3 = TD3Config()
    obs_dim = observation_space(parse_mission(bench_mission(args.seed))).shape[0]
    alone = updates_alone(obs_dim, td3, threads=args.learner_threads)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    rows = {
        "graft: Ray actors + replay server + learner at full speed": decoupled(args, td3),
        f"naive loop: {args.naive_updates} TD3 update(s) inside each client's step": naive(
            args, td3
        ),
    }
    ray.shutdown()
    print(
        f"\n{CLIENTS} asynchronous clients at {MS_PER_TICK} ms ticks, TD3 (batch "
        f"{td3.batch_size}, {td3.hidden_sizes}, obs {obs_dim}), {os.cpu_count()} cores; "
        f"{args.measure:.0f} s measured after {args.warmup:.0f} s warm-up; learner "
        f"{args.learner_threads} torch thread(s), nice +{args.learner_nice}"
    )
    print(
        "| loop | ticks skipped | steps/s per client | world ticks/s | own step latency "
        "p50 / p99 (ms) | TD3 updates/s |"
    )
    print("|---|---|---|---|---|---|")
    for name, r in rows.items():
        print(
            f"| {name} | {100 * r['skipped']:.2f}% | {r['steps_per_s']:.1f} | "
            f"{r['ticks_per_s']:.1f} | {r['p50']:.1f} / {r['p99']:.1f} | "
            f"{r['updates_per_s']:.1f} |"
        )
    print(
        f"reference: the same TD3 update alone in one process, {args.learner_threads} torch "
        f"thread(s), in-memory batch, no actors: {alone:.1f} updates/s"
    )
    graft = next(iter(rows.values()))
    print(
        f"graft's actors each adopted >= {graft['versions']} broadcast weight versions and "
        f"waited at most {graft['insert_wait_s']:.2f} s in all for their background inserts; "
        f"every client acted at nice {max(r['nice'] for r in rows.values())}, the learner at "
        f"Ray's worker nice 15 + {args.learner_nice}, world and replay servers at 0"
    )
    for name, r in rows.items():
        if r["losses"]:
            print(f"{name}: {r['losses']} connection losses")


def main() -> None:
    """Print the tables."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--part", choices=("all", "ticks", "decoupling"), default="all")
    ap.add_argument("--ticks", type=int, default=3000, help="ticks without rendering")
    ap.add_argument("--render-ticks", type=int, default=300, help="ticks with rendering")
    ap.add_argument("--size", type=int, default=64, help="frame width = height")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--warmup", type=float, default=20.0, help="seconds before measuring")
    ap.add_argument("--measure", type=float, default=40.0, help="seconds measured")
    ap.add_argument("--episode-steps", type=int, default=600, help="actor-side episode limit")
    ap.add_argument("--naive-updates", type=int, default=1, help="updates per naive step")
    ap.add_argument("--learner-threads", type=int, default=1, help="torch threads (learner)")
    ap.add_argument("--learner-nice", type=int, default=0, help="learner's nice increment")
    args = ap.parse_args()
    if args.part in ("all", "ticks"):
        ticks_table(args)
    if args.part in ("all", "decoupling"):
        decoupling_table(args)


if __name__ == "__main__":
    main()
