"""Chaos benchmark: a real replay server process under the faults and loads of ordinary use.

1. SIGKILL/restart cycles while writers insert (periodic checkpoints on, so kills also
   land mid-checkpoint): acknowledged items lost and doubled.
2. Connections cut (TCP reset by a proxy) while inserts wait on a rate limiter, the
   writers resending on reconnect: acknowledged items lost and doubled.
3. 64 idle sample streams + 16 writers: inserts and health checks answered within a
   5 s / 2 s deadline, insert latency.
4. Server RSS growth over scenarios 2 and 3 (one server process each).
5. A Minecraft world server (``minecraft serve``, default limits) under 300 idle
   connections, 16 connections announcing a 4 MiB message and sending 1 byte, and a
   2000x2000 VideoProducer mission: its threads, RSS and replies.
6. 10,000 refused requests of each kind the replay server refuses (most carrying a 1 MiB
   field): its RSS before and after each kind, flat within 10 %.

Every table is audited the same way: the server is stopped gracefully, restarted on its
folder with a plain min-size limiter, and read whole. Loopback only.

    python bench/chaos.py [--quick] [--only-refusals] [--refusals N]
"""

from __future__ import annotations

import argparse
import random
import time
from collections.abc import Callable
from typing import Any

from chaos_faults import dropped_connections, kill_restart  # bench/, beside this script
from chaos_load import idle_streams
from chaos_refusals import FLAT, refused_requests
from chaos_world import world_server_limits


def timed(what: str, run: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    print(f"... {what}", flush=True)
    start = time.perf_counter()
    result = run()
    result["wall s"] = time.perf_counter() - start
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="about a minute (fewer cycles)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--refusals", type=int, default=None, help="refused requests of each kind (10,000)"
    )
    parser.add_argument("--only-refusals", action="store_true", help="run part 6 only")
    args = parser.parse_args()
    random.seed(args.seed)
    cycles = 5 if args.quick else 24
    load_s = 8.0 if args.quick else 60.0
    refusals = args.refusals or (1_000 if args.quick else 10_000)
    if args.only_refusals:
        flat = print_refusals(timed(f"{refusals:,} refused requests of each kind",
                                    lambda: refused_requests(refusals)))  # fmt: skip
        raise SystemExit(0 if flat else 1)

    kill = timed(f"{cycles} SIGKILL/restart cycles, 4 writers", lambda: kill_restart(cycles))
    drop = timed(
        f"{cycles} connection cuts while inserts wait on the rate limiter, 4 writers",
        lambda: dropped_connections(cycles),
    )
    idle = timed(f"64 idle sample streams + 16 writers for {load_s:.0f} s",
                 lambda: idle_streams(load_s))  # fmt: skip
    world = timed("a world server: 300 idle connections, 16 announcing 4 MiB, a 2000x2000 "
                  "frame", world_server_limits)  # fmt: skip
    refused = timed(f"{refusals:,} refused requests of each kind",
                    lambda: refused_requests(refusals))  # fmt: skip

    print()
    print("| fault | cycles | acked items | lost | doubled | stored, not acked | writer errors |")
    print("|---|---|---|---|---|---|---|")
    for name, r in (("SIGKILL + restart", kill), ("connections cut while waiting", drop)):
        print(
            f"| {name} | {r['cycles']} | {r['acked items']:,} | {r['lost']} | {r['doubled']} "
            f"| {r['stored unacked']} | {r['writer errors']} |"
        )
    print()
    print("| load | inserts answered | inserts failed | health answered | p50 ms | p99 ms |")
    print("|---|---|---|---|---|---|")
    codes = f" ({', '.join(idle['failure codes'])})" if idle["failure codes"] else ""
    print(
        f"| 64 idle sample streams + 16 writers, {load_s:.0f} s | {idle['inserts answered']:,} "
        f"| {idle['inserts failed']}{codes} | {idle['health answered']}/{idle['health checks']} "
        f"| {idle['p50 ms']:.1f} | {idle['p99 ms']:.1f} |"
    )
    print()
    print("targets: 0 lost and 0 doubled; every insert and health check answered, p99 <= 100 ms")
    for name, r in (("connection cuts", drop), ("idle streams + writers", idle)):
        start, end = r["rss"]
        print(
            f"server RSS over {name}: {start:.0f} -> {end:.0f} MiB ({end - start:+.1f} MiB "
            f"in {r['wall s']:.0f} s)"
        )
    ok, reason, ms = world["frame reply"]
    print()
    print(
        f"world server: 300 idle connections -> {world['idle refused']} refused at once, "
        f"+{world['idle threads']} threads, {world['idle rss']:+.1f} MiB RSS; 16 connections "
        f"announcing 4 MiB -> {world['announcing rss']:+.1f} MiB RSS; a 2000x2000 "
        f"VideoProducer -> answered {ok} in {ms:.0f} ms, peak RSS "
        f"{world['frame peak']:+.1f} MiB: {reason}"
    )
    print_refusals(refused)


def print_refusals(r: dict[str, Any]) -> bool:
    """Part 6's table: the server's RSS over each kind of refused request; whether each
    kind left it flat (after/before at most FLAT)."""
    print()
    print(
        f"| refused request, {r['n']:,} each | status | RSS before MiB | peak MiB | after MiB "
        f"| ratio after/before | within {FLAT - 1:.0%} |"
    )
    print("|---|---|---|---|---|---|---|")
    flat = []
    for kind in r["kinds"]:
        before, after = kind["rss"]
        flat.append(after / before <= FLAT)
        print(
            f"| {kind['kind']} | {', '.join(kind['codes'])} | {before:.0f} | {kind['peak']:.0f} "
            f"| {after:.0f} | {after / before:.3f} | {'yes' if flat[-1] else 'NO'} |"
        )
    print(
        f"server RSS: {r['started']:.0f} MiB at start, {r['warm']:.0f} MiB after the warm-up, "
        f"{r['end']:.0f} MiB after all {r['n'] * len(r['kinds']):,} refused requests "
        f"(ratio {r['end'] / r['warm']:.3f})"
    )
    print(f"each kind within {FLAT - 1:.0%}: {'yes' if all(flat) else 'NO'}")
    return all(flat)


if __name__ == "__main__":
    main()
