"""``graft minecraft serve`` (one world server) and ``graft minecraft view`` (PNG frames of
a short episode). Run standalone with ``python -m actors.minecraft.cli minecraft ...``."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from pathlib import Path
from typing import Optional

import numpy as np

from actors.minecraft.malmo import protocol as P


def _serve(args: argparse.Namespace) -> int:
    from actors.minecraft.sim.server import WorldServer

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    server = WorldServer(args.host, args.port, seed=args.seed, ms_per_tick=args.ms_per_tick)
    server.start()
    print(f"graft minecraft world server on {args.host}:{server.port}", flush=True)
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        server.stop()
    return 0


def _view(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from actors.minecraft.malmo.client import MalmoClient
    from actors.minecraft.malmo.mission_xml import mission_xml
    from actors.minecraft.sim.server import WorldServer

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    with WorldServer(port=0, seed=args.seed) as server:
        client = MalmoClient("127.0.0.1", server.port, synchronous=True, seed=args.seed)
        client.init(mission_xml(width=args.width, height=args.height))
        frame = client.reset()
        every = max(1, args.steps // max(args.frames - 1, 1))
        saved: list[Path] = []
        for t in range(args.steps + 1):
            if t % every == 0 and len(saved) < args.frames:
                path = out / f"frame_{t:05d}.png"
                big = np.repeat(np.repeat(frame[..., :3], args.scale, 0), args.scale, 1)
                plt.imsave(path, big)
                saved.append(path)
            # A wandering walk: forward, jumping, turning now and then.
            turn = float(rng.uniform(-0.6, 0.6)) if t % 40 < 8 else 0.0
            r = client.step(f"move 1\njump 1\nturn {turn:.2f}\npitch 0")
            frame = r.frame
            if r.done:
                break
        client.close()
    for p in saved:
        print(p)
    return 0


def _tree(args: argparse.Namespace) -> int:
    from actors.minecraft.agent.diamond_tree import build_tree
    from actors.minecraft.agent.tree_render import ascii_tree, render_png

    root, _ = build_tree()
    print(ascii_tree(root))
    if args.png:
        print(f"wrote {render_png(root, Path(args.png))}")
    return 0


def add_minecraft_commands(subparsers: argparse._SubParsersAction) -> None:
    """Register ``minecraft serve``, ``view`` and ``tree`` on a subparsers object.

    Each leaf parser sets ``func`` (``args.func(args) -> int``).
    """
    mc = subparsers.add_parser("minecraft", help="simulated Minecraft (MalmoEnv) worlds")
    sub = mc.add_subparsers(dest="minecraft_command", required=True)
    serve = sub.add_parser("serve", help="run one world server speaking MalmoEnv")
    serve.add_argument("--port", type=int, default=P.DEFAULT_PORT, help="TCP port (0: any)")
    serve.add_argument("--seed", type=int, default=0, help="base world seed")
    serve.add_argument("--ms-per-tick", type=int, default=50, help="default tick period")
    serve.add_argument("--host", default="127.0.0.1", help="interface to bind")
    serve.set_defaults(func=_serve)
    view = sub.add_parser("view", help="save PNG frames of a short episode")
    view.add_argument("--seed", type=int, default=0, help="world seed")
    view.add_argument("--steps", type=int, default=200, help="ticks to run")
    view.add_argument("--frames", type=int, default=6, help="frames to save")
    view.add_argument("--out", default="minecraft_frames", help="output directory")
    view.add_argument("--width", type=int, default=96, help="frame width")
    view.add_argument("--height", type=int, default=64, help="frame height")
    view.add_argument("--scale", type=int, default=4, help="upscaling of saved PNGs")
    view.set_defaults(func=_view)
    tree = sub.add_parser("tree", help="print the obtain-diamond behaviour tree, save a PNG")
    tree.add_argument("--png", default="diamond_tree.png", help="PNG path ('' for none)")
    tree.set_defaults(func=_tree)


def main(argv: Optional[list[str]] = None) -> int:
    """Entry point for ``python -m actors.minecraft.cli minecraft ...``."""
    parser = argparse.ArgumentParser(prog="graft")
    sub = parser.add_subparsers(dest="command", required=True)
    add_minecraft_commands(sub)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
