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

    python bench/minecraft_suite.py                       # all parts
    python bench/minecraft_suite.py --part decoupling [--warmup 20 --measure 40 --seed 1]
    python bench/minecraft_suite.py --part clients [--clients 8 16 24 32 48 --per-actor 8]
"""

from __future__ import annotations

import argparse

from minecraft_clients import clients_sweep  # bench/, beside this script
from minecraft_decoupling import decoupling_table
from minecraft_encoding import encoding_cost
from minecraft_ticks import ticks_table


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
