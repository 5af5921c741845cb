"""Decoding + encoding one observation: the per-block grid encoding against the block-id
table, on the sample mission's real observations, interleaved in one process.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from typing import Any

from pooled_clients import encode_per_block  # bench/, beside this script

from minecraft.agent import grid_encoding
from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.pool import ServerPool
from minecraft.sim.timing import IDEAL


def encoding_cost(args: argparse.Namespace) -> None:
    """Part 0: decoding + encoding one observation, the per-block baseline against the
    block-id table, on the sample mission's real observations, interleaved in one process."""
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
