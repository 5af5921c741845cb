"""Ticks per second of one simulated Minecraft world server in synchronous mode, through
the MalmoEnv protocol, without and with rendering.

The server runs in its own process (``minecraft serve``), the client is graft's
``MalmoClient``; each step advances exactly one tick and returns the observations of the
sample obtain-diamond mission (full stats, 15×15×15 grid, inventory, entities, ray).

    python bench/minecraft.py [--ticks 3000] [--size 64]

The decoupling table of issue 5 (4 asynchronous clients at 50 ms ticks beside a learner
training at full speed, against the naive loop) needs the Minecraft Ray actors and the
replay client; it is not measured here yet.
"""

from __future__ import annotations

import argparse
import time

from actors.minecraft.client import MalmoClient
from actors.minecraft.missions import mission_xml
from actors.minecraft.pool import ServerPool


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


def main() -> None:
    """Print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ticks", type=int, default=3000, help="ticks without rendering")
    ap.add_argument("--render-ticks", type=int, default=300, help="ticks with rendering")
    ap.add_argument("--size", type=int, default=64, help="frame width = height")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    with ServerPool(1, base_port=0, seed=args.seed) as pool:
        port = pool.ports[0]
        light = ticks_per_second(port, size=None, ticks=args.ticks, seed=args.seed, full=False)
        plain = ticks_per_second(port, size=None, ticks=args.ticks, seed=args.seed)
        drawn = ticks_per_second(port, size=args.size, ticks=args.render_ticks, seed=args.seed)
    print("| one world server, synchronous, through MalmoEnv | ticks/s |")
    print("|---|---|")
    print(f"| no rendering, full stats only (target >= 2000) | {light:,.0f} |")
    print(f"| no rendering, + 15x15x15 grid, inventory, entities, ray | {plain:,.0f} |")
    print(f"| rendering {args.size}x{args.size} RGB, + all observations | {drawn:,.0f} |")
    print("\ndecoupling table (4 async clients + learner vs naive loop): not yet measured; "
          "needs the Minecraft Ray actors and the replay client.")  # fmt: skip


if __name__ == "__main__":
    main()
