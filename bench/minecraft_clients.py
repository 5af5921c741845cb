"""The clients sweep: N real-time clients in env actors of several clients each, each client at
its own pace, beside a TD3 learner at full speed; skipped ticks, CPU per client, updates/s
(CSV + PNG), after actor CPU per tick before and after in the same run.
"""

from __future__ import annotations

import argparse
import csv
import os

import ray
from minecraft_rig import MS_PER_TICK, bench_mission, measure, rig, summary  # bench/
from pooled_clients import actors_for
from tqdm import tqdm

from actors.task import EnvSpec
from learner.td3.config import TD3Config

BENCH_DIR = os.path.dirname(os.path.abspath(__file__))


def clients_run(
    args: argparse.Namespace, td3: TD3Config, *, clients: int, per_actor: int, baseline: bool
) -> dict[str, float]:
    """`clients` real-time clients at 50 ms ticks, `per_actor` of them in each env actor
    (each at its own pace, the vectorised encoding) or, as `baseline`, one per actor with the
    per-block encoding; a TD3 learner trains at full speed beside them."""
    groups = actors_for(clients, 1 if baseline else per_actor)
    with rig(args, td3, clients=clients, max_size=50_000) as setup:
        actors = []
        for group in groups:
            kwargs = {
                "addresses": [f"127.0.0.1:{setup.pool.ports[c]}" for c in group],
                "mission_xml": bench_mission(args.seed), "world_seed": args.seed + group[0],
                "max_episode_steps": args.episode_steps, "per_block_encoding": baseline,
            }  # fmt: skip
            env = EnvSpec("pooled_clients:pooled_mission", kwargs, None, (BENCH_DIR,))
            actors.append(
                setup.env_actor(
                    env,
                    num_envs=len(group),
                    seed=args.seed + group[0],
                    async_envs=not baseline,
                    num_cpus=0.01,
                )
            )
        window = measure(setup, actors, warmup=args.warmup, seconds=args.measure)
    before, after, worlds = window.before, window.after, window.world_cpu_s
    row = summary(after, window.updates_per_s)
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
