"""The decoupling table: 4 real-time clients as graft runs them (env actors streaming to the
replay server beside a TD3 learner at full speed) against the paper's naive loop (each client
trains its own TD3 between two steps); the fraction of world ticks the clients never saw.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import ray
import torch
from minecraft_rig import MS_PER_TICK, bench_mission, measure, rig, summary  # bench/
from naive_loop import NaiveLoop  # Ray workers import it too (Ray puts bench/ on their path)

from actors.task import EnvSpec
from learner.td3.builder import make_td3_learner
from learner.td3.config import TD3Config
from minecraft.agent.mission_env import ACTION_SPACE, ENV_ID, observation_space
from minecraft.malmo.mission import parse_mission
from minecraft.sim.pool import ServerPool

CLIENTS = 4


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
    with rig(args, td3, clients=CLIENTS, max_size=100_000) as setup:
        actors = [
            setup.env_actor(
                EnvSpec(ENV_ID, env_kwargs(port, args.seed + i, args.episode_steps)),
                num_envs=1,
                seed=args.seed + i,
            )
            for i, port in enumerate(setup.pool.ports)
        ]
        window = measure(setup, actors, warmup=args.warmup, seconds=args.measure)
    return summary(window.final, window.updates_per_s)


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
            )
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
    return summary(reports, (after - before) / reports[0]["perf/measure_s"])


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
