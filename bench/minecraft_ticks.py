"""Ticks per second of one simulated world server in synchronous mode (ideal timing), through
the MalmoEnv protocol with graft's ``MalmoClient``, without and with rendering.
"""

from __future__ import annotations

import argparse
import re
import time

from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.pool import ServerPool
from minecraft.sim.timing import IDEAL


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
