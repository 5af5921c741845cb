"""Minecraft benchmarks: world server ticks per second, the decoupling table, the clients sweep.

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

3. The clients sweep: N real-time clients (default 8, 16, 24, 32, 48; 50 ms ticks, one
   world server process each) driven by env actors of ``--per-actor`` clients each,
   each at its own pace (``async_envs``), acted for in batched policy calls, beside a TD3
   learner at full speed:
   skipped ticks, world ticks/s, actor and world-server CPU per client, updates/s (CSV +
   PNG). First, in the same run, actor CPU per tick before (one client per actor, the
   per-block grid encoding, ``pooled_clients.encode_per_block``) and after.

    python bench/minecraft.py                       # all parts
    python bench/minecraft.py --part decoupling [--warmup 20 --measure 40 --seed 1]
    python bench/minecraft.py --part clients [--clients 8 16 24 32 48 --per-actor 8]
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
from pooled_clients import actors_for

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
from service.run.replay_host.process import ReplayProcess
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


# ------------------------------------------------------------------ encoding cost
def encoding_cost(args: argparse.Namespace) -> None:
    """Part 0: decoding + encoding one observation, the per-block baseline against the
    block-id table, on the sample mission's real observations, interleaved in one process."""
    import json

    from pooled_clients import encode_per_block

    from actors.minecraft.agent import grid_encoding

    with ServerPool(1, base_port=0, seed=args.seed, timing=IDEAL) as pool:
        client = MalmoClient("127.0.0.1", pool.ports[0], synchronous=True, seed=args.seed)
        client.init(mission_xml(width=None, time_limit_ms=None))
        client.reset()
        texts = []
        for i in range(200):
            r = client.step(["move 1\njump 1", "turn 0.5", "move 1\nattack 1"][(i // 20) % 3])
            if r.info:
                texts.append(json.dumps(r.info))
        client.close()
    grid = next(k for k, v in json.loads(texts[0]).items() if isinstance(v, list) and len(v) > 1000)

    def per_tick_ms(encode: Any) -> float:
        t = time.thread_time()
        for text in texts:
            encode(json.loads(text), k=8, grid=grid)
        return 1000 * (time.thread_time() - t) / len(texts)

    rounds = [(per_tick_ms(encode_per_block), per_tick_ms(grid_encoding.encode)) for _ in range(5)]
    before = min(r[0] for r in rounds)
    after = min(r[1] for r in rounds)
    decode = min(per_tick_ms(lambda info, **_: info) for _ in range(5))
    print(f"\nobservation decoding + encoding, {len(texts)} real observations "
          f"({len(texts[0]):,} B of JSON, {grid} grid), CPU ms per observation, "
          "best of 5:")  # fmt: skip
    print("| encoding | JSON decode + encode (ms) | encode alone (ms) |\n|---|---|---|")
    print(f"| per-block (before) | {before:.3f} | {before - decode:.3f} |")
    print(f"| block-id table (after) | {after:.3f} | {after - decode:.3f} |")
    print(f"ratio after / before: {after / before:.2f} (encode alone "
          f"{(after - decode) / (before - decode):.2f}); load {os.getloadavg()}")  # fmt: skip


# ------------------------------------------------------------------ clients sweep
BENCH_DIR = os.path.dirname(os.path.abspath(__file__))


def _proc_cpu_s(pid: int) -> float:
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def clients_run(
    args: argparse.Namespace, td3: TD3Config, *, clients: int, per_actor: int, baseline: bool
) -> dict[str, float]:
    """`clients` real-time clients at 50 ms ticks, `per_actor` of them in each env actor
    (each at its own pace, the vectorised encoding) or, as `baseline`, one per actor with the
    per-block encoding; a TD3 learner trains at full speed beside them."""
    obs_space = observation_space(parse_mission(bench_mission(args.seed)))
    low, high = ACTION_SPACE.low, ACTION_SPACE.high
    network = make_actor_network(obs_space.shape[0], ACTION_SPACE.shape[0], low, high, td3)
    behaviour = GaussianBehaviour(network, std=td3.exploration_noise, low=low, high=high)
    table = {
        "name": TABLE, "max_size": 50_000,
        "signature": replay_signature(obs_space, behaviour.columns()),
        "rate_limiter": {"kind": "min_size", "min_size": td3.batch_size},
    }  # fmt: skip
    segment = Segment(TABLE, steps=10**9, pending_inserts=PENDING_INSERTS)
    groups = actors_for(clients, 1 if baseline else per_actor)
    with ServerPool(clients, base_port=0, seed=args.seed, ms_per_tick=MS_PER_TICK) as pool:
        with ReplayProcess([table]) as server:
            replay = ReplayClient(server.address)
            broadcaster = WeightBroadcaster.remote()
            learner = FullSpeedLearner.remote(
                replay, broadcaster, obs_dim=obs_space.shape[0], td3=td3, seed=args.seed,
                threads=args.learner_threads, nice=args.learner_nice,
            )  # fmt: skip
            actors = []
            for group in groups:
                kwargs = {
                    "addresses": [f"127.0.0.1:{pool.ports[c]}" for c in group],
                    "mission_xml": bench_mission(args.seed), "world_seed": args.seed + group[0],
                    "max_episode_steps": args.episode_steps, "per_block_encoding": baseline,
                }  # fmt: skip
                actors.append(
                    EnvActor.options(num_cpus=0.01).remote(
                        env=EnvSpec("pooled_clients:pooled_mission", kwargs, None, (BENCH_DIR,)),
                        num_envs=len(group),
                        seed=args.seed + group[0],
                        replay=replay,
                        weights=WeightSubscriber(broadcaster),
                        behaviour=behaviour,
                        steps_per_insert=max(1, INSERT_EVERY // len(group)),
                        nice=0,
                        async_envs=not baseline,
                    )  # fmt: skip
                )
            ray.get([a.report.remote() for a in actors])  # constructed, connected
            training = learner.run.remote()
            runs = [a.run.remote([segment]) for a in actors]
            time.sleep(args.warmup)
            ray.get([learner.mark.remote(), *(a.restart_meters.remote() for a in actors)])
            before = ray.get([a.report.remote() for a in actors])
            worlds0 = sum(_proc_cpu_s(p.pid) for p in pool.procs)
            time.sleep(args.measure)
            after = ray.get([a.report.remote() for a in actors])
            worlds = sum(_proc_cpu_s(p.pid) for p in pool.procs) - worlds0
            ray.get(broadcaster.stop.remote())
            ray.get(runs)
            ray.get(learner.stop.remote())
            trained = ray.get(training)
            ray.get([a.close.remote() for a in actors])
            for handle in [*actors, learner, broadcaster]:
                ray.kill(handle)
            replay.close()
    row = _summary(after, trained["updates_per_s"])
    actor_cpu = sum(a["perf/process_cpu_s"] - b["perf/process_cpu_s"]
                    for b, a in zip(before, after, strict=True))  # fmt: skip
    seen = sum(r["perf/ticks_seen"] for r in after)
    ticks = seen + sum(r["perf/ticks_skipped"] for r in after)
    row.update(
        ticks_per_s=ticks / after[0]["perf/measure_s"] / clients,  # per client, not per actor
        clients=clients, actors=len(actors),
        actor_cpu_per_client=actor_cpu / args.measure / clients,
        actor_ms_per_tick=1000 * actor_cpu / max(seen, 1),
        world_cpu_per_client=worlds / args.measure / clients,
    )  # fmt: skip
    return row


CLIENTS_HEADER = (
    "| clients | actors | ticks skipped | world ticks/s per client | actor CPU per client "
    "(cores) | actor CPU per tick (ms) | world server CPU per client (cores) | own step "
    "latency p99 (ms) | TD3 updates/s |\n|---|---|---|---|---|---|---|---|---|"
)


def _clients_line(r: dict[str, float]) -> str:
    return (
        f"| {r['clients']:.0f} | {r['actors']:.0f} | {100 * r['skipped']:.2f}% | "
        f"{r['ticks_per_s']:.1f} | {r['actor_cpu_per_client']:.3f} | "
        f"{r['actor_ms_per_tick']:.2f} | {r['world_cpu_per_client']:.3f} | {r['p99']:.1f} | "
        f"{r['updates_per_s']:.1f} |"
    )


def clients_sweep(args: argparse.Namespace) -> None:
    """Part 3: actor CPU per tick before vs after (same run), then the clients sweep."""
    import csv

    from tqdm import tqdm

    td3 = TD3Config()
    print(f"load before: {os.getloadavg()}")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    n0 = args.compare_clients
    compare = {
        f"before: {n0} actors x 1 client, per-block encoding, one step at a time": clients_run(
            args, td3, clients=n0, per_actor=1, baseline=True
        ),
        f"after: asynchronous clients, {args.per_actor} per actor, block-id table": (
            clients_run(args, td3, clients=n0, per_actor=args.per_actor, baseline=False)
        ),
    }
    print(f"\n{n0} real-time clients at {MS_PER_TICK} ms ticks, learner at full speed:")
    print(
        CLIENTS_HEADER.replace("| clients |", "| setup | clients |", 1).replace(
            "|---|", "|---|---|", 1
        )
    )
    for name, r in compare.items():
        print(f"| {name} " + _clients_line(r))
    before, after = compare.values()
    print(f"actor CPU per tick: {before['actor_ms_per_tick']:.2f} ms before, "
          f"{after['actor_ms_per_tick']:.2f} ms after "
          f"(ratio {after['actor_ms_per_tick'] / before['actor_ms_per_tick']:.2f})")  # fmt: skip
    rows = []
    for n in tqdm(args.clients, unit="point", desc="clients sweep"):
        rows.append(clients_run(args, td3, clients=n, per_actor=args.per_actor, baseline=False))
        print(f"load after {n} clients: {os.getloadavg()}")
    ray.shutdown()
    print(f"\nclients sweep, {args.per_actor} clients per actor, {MS_PER_TICK} ms ticks, "
          f"{args.measure:.0f} s measured after {args.warmup:.0f} s:")  # fmt: skip
    print(CLIENTS_HEADER)
    for r in rows:
        print(_clients_line(r))
    out = os.path.join(args.out, "minecraft-clients")
    os.makedirs(args.out, exist_ok=True)
    with open(out + ".csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot_clients(rows, out + ".png")
    print(f"results: {out}.csv\nfigure: {out}.png")


def plot_clients(rows: list[dict[str, float]], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["clients"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].plot(n, [100 * r["skipped"] for r in rows], "o-")
    axes[0].axhline(1.0, color="k", linestyle="--", linewidth=0.8)
    axes[0].set_ylabel("ticks skipped (%)")
    axes[1].plot(n, [r["actor_cpu_per_client"] for r in rows], "o-", label="actor")
    axes[1].plot(n, [r["world_cpu_per_client"] for r in rows], "s-", label="world server")
    axes[1].set_ylabel("CPU per client (cores)")
    axes[1].legend()
    axes[2].plot(n, [r["updates_per_s"] for r in rows], "o-")
    axes[2].set_ylabel("learner TD3 updates/s")
    for ax in axes:
        ax.set_xlabel("real-time clients (50 ms ticks)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main() -> None:
    """Print the tables."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--part", choices=("all", "ticks", "decoupling", "encoding", "clients"), default="all"
    )
    ap.add_argument("--clients", type=int, nargs="+", default=[8, 16, 24, 32, 48])
    ap.add_argument("--per-actor", type=int, default=8, help="clients per env actor (sweep)")
    ap.add_argument("--compare-clients", type=int, default=8, help="clients, before vs after")
    ap.add_argument("--out", default="runs/bench-minecraft")
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
    if args.part in ("all", "encoding"):
        encoding_cost(args)
    if args.part in ("all", "clients"):
        clients_sweep(args)


if __name__ == "__main__":
    main()
