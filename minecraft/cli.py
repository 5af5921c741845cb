"""``graft minecraft serve`` (one world server) and ``graft minecraft view`` (PNG frames of
a short episode, or with ``--gif`` the obtain-diamond tree as an animated GIF). Run
standalone with ``python -m minecraft.cli minecraft ...``."""

from __future__ import annotations

import argparse
import dataclasses
import logging
import signal
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np

from minecraft.malmo import protocol as P
from minecraft.sim.limits import DEFAULT_LIMITS, Limits
from minecraft.sim.timing import IDEAL, JOIN_S, WAIT_S, Timing

if TYPE_CHECKING:
    from minecraft.agent.corrections import Corrections


def _timing(args: argparse.Namespace) -> Timing:
    try:
        if args.ideal:
            return dataclasses.replace(IDEAL, join_s=args.join_s)
        return Timing(
            loading_s=args.loading_s, ending_s=args.ending_s, fps=args.fps, wait_s=args.wait_s,
            join_s=args.join_s,
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(f"graft minecraft serve: {e}") from None


def _limits(args: argparse.Namespace) -> Limits:
    try:
        return Limits(
            max_frame_pixels=args.max_frame_pixels, max_grid_cells=args.max_grid_cells,
            max_message_bytes=args.max_message_bytes, max_connections=args.max_connections,
            idle_timeout_s=args.idle_timeout_s,
        )  # fmt: skip
    except ValueError as e:
        field = str(e).split()[0]  # each message starts with the field: name its flag
        flag = "--" + field.replace("_", "-")
        raise SystemExit(f"graft minecraft serve: {str(e).replace(field, flag, 1)}") from None


def warm_up() -> None:
    """What a world server loads before it serves: the simulator and the frame's compiled
    kernels. A fork server (`service.forkserver`, as `ServerPool` starts world servers)
    runs it once, and every world server forked from it starts with them loaded."""
    from minecraft.sim import render, server  # noqa: F401 - loaded to be inherited

    render.warm_up()


def _serve(args: argparse.Namespace) -> int:
    from minecraft.sim.server import WorldServer

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if args.instances < 1:
        raise SystemExit(f"graft minecraft serve: --instances must be >= 1, got {args.instances}")
    if not 0.0 <= args.diamond_keep <= 1.0:
        raise SystemExit(
            f"graft minecraft serve: --diamond-keep must be within [0, 1], got {args.diamond_keep}"
        )
    timing, limits = _timing(args), _limits(args)
    # Several instances in one process: a multi-agent mission's roles join each other.
    servers = [
        WorldServer(args.host, args.port + i if args.port else 0, seed=args.seed + i,
                    ms_per_tick=args.ms_per_tick, timing=timing, limits=limits,
                    diamond_keep=args.diamond_keep)
        for i in range(args.instances)
    ]  # fmt: skip

    def stop(*_: object) -> None:
        for server in servers:
            server.stop()

    # Before any server listens: a SIGTERM sent the moment one answers stops them all
    # (a server stopped before its start returns from serve_forever at once).
    signal.signal(signal.SIGTERM, stop)
    for server in servers:
        server.start()
        print(f"graft minecraft world server ({timing.mode} timing) on "
              f"{args.host}:{server.port}", flush=True)  # fmt: skip
    try:
        servers[0].serve_forever()
    except KeyboardInterrupt:
        stop()
    return 0


def _view(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from minecraft.malmo.client import MalmoClient
    from minecraft.malmo.mission_xml import mission_xml
    from minecraft.sim.server import WorldServer

    if args.gif:
        return _view_tree(args)
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


def _view_tree(args: argparse.Namespace) -> int:
    from minecraft.agent.tree_gif import record_gif
    from minecraft.malmo.mission_xml import obtain_diamond
    from minecraft.sim.server import WorldServer

    if args.every < 1 or args.steps < 1 or args.ticks_per_step < 1:
        print("graft minecraft view: --every, --steps and --ticks-per-step must be at least 1",
              file=sys.stderr)  # fmt: skip
        return 2
    corrections = None
    if args.controller or args.travel_while:
        if args.load_corrections is None:
            print("graft minecraft view: --controller needs graft's service (run it as "
                  "`graft minecraft view`)", file=sys.stderr)  # fmt: skip
            return 2
        try:
            corrections = args.load_corrections(
                [Path(c) for c in args.controller], args.travel_while
            )
        except (ValueError, FileNotFoundError) as error:
            print(f"graft minecraft view: {error}", file=sys.stderr)
            return 2
    with WorldServer(port=0, seed=args.seed) as server:
        result, n = record_gif(
            server.port,
            obtain_diamond(seed=args.seed),
            Path(args.gif),
            seed=args.seed,
            max_ticks=args.steps,
            every=args.every,
            ticks_per_step=args.ticks_per_step,
            corrections=corrections,
        )
    print(f"wrote {args.gif}: {n} frames; {result.stage} reached at tick {result.ticks}")
    return 0


def _tree(args: argparse.Namespace) -> int:
    from minecraft.agent.diamond_tree import build_tree
    from minecraft.agent.tree_render import ascii_tree, render_png

    root, _ = build_tree()
    print(ascii_tree(root))
    if args.png:
        print(f"wrote {render_png(root, Path(args.png))}")
    return 0


def add_minecraft_commands(
    subparsers: argparse._SubParsersAction,
    load_corrections: Optional[Callable[[list[Path], list[str]], Corrections]] = None,
) -> None:
    """Register ``minecraft serve``, ``view`` and ``tree`` on a subparsers object.

    Each leaf parser sets ``func`` (``args.func(args) -> int``). ``load_corrections``
    (trained run folders -> the corrections they make; given by graft's CLI, which may
    load runs) serves ``view --controller``.
    """
    mc = subparsers.add_parser("minecraft", help="simulated Minecraft (MalmoEnv) worlds")
    sub = mc.add_subparsers(dest="minecraft_command", required=True)
    _add_serve(sub)
    _add_view(sub, load_corrections)
    tree = sub.add_parser("tree", help="print the obtain-diamond behaviour tree, save a PNG")
    tree.add_argument("--png", default="diamond_tree.png", help="PNG path ('' for none)")
    tree.set_defaults(func=_tree)


def _add_serve(sub: argparse._SubParsersAction) -> None:
    serve = sub.add_parser("serve", help="run one world server speaking MalmoEnv")
    serve.add_argument("--port", type=int, default=P.DEFAULT_PORT, help="TCP port (0: any)")
    serve.add_argument("--seed", type=int, default=0, help="base world seed")
    serve.add_argument("--ms-per-tick", type=int, default=50, help="default tick period")
    serve.add_argument(
        "--diamond-keep",
        type=float,
        default=1.0,
        help="fraction of diamond veins a default world keeps (drawn per vein from the "
        "world seed, the rest stone; a mission's generatorOptions diamondKeep overrides it)",
    )
    serve.add_argument("--host", default="127.0.0.1", help="interface to bind")
    serve.add_argument(
        "--instances",
        type=int,
        default=1,
        help="Minecraft instances on consecutive ports (multi-agent missions)",
    )
    serve.add_argument(
        "--ideal",
        action="store_true",
        help="graft's convenient pacing instead of real Malmo's: no loading or "
        "ending delay, a new mission replaces the running one, one frame per "
        "tick, commands queued without a VideoProducer",
    )
    serve.add_argument(
        "--loading-s",
        type=float,
        default=1.0,
        help="real timing: seconds a mission loads before its first frame",
    )
    serve.add_argument(
        "--ending-s",
        type=float,
        default=0.5,
        help="real timing: seconds after a mission ends before the next starts",
    )
    serve.add_argument(
        "--fps",
        type=float,
        default=60.0,
        help="real timing: frames per second, independent of ticks",
    )
    serve.add_argument(
        "--wait-s",
        type=float,
        default=WAIT_S,
        help="longest wait of a Peek or step for a frame (Malmo: 3 s)",
    )
    serve.add_argument(
        "--join-s",
        type=float,
        default=JOIN_S,
        help="seconds a multi-agent mission waits for its other roles before it ends "
        "(Malmo: 2,000 client ticks, 100 s)",
    )
    d = DEFAULT_LIMITS
    limit_flags: list[tuple[str, type, object, str]] = [
        ("--max-frame-pixels", int, d.max_frame_pixels, "largest VideoProducer Width×Height"),
        ("--max-grid-cells", int, d.max_grid_cells, "most ObservationFromGrid cells a mission"),
        ("--max-message-bytes", int, d.max_message_bytes, "longest request message"),
        ("--max-connections", int, d.max_connections, "most open connections"),
        ("--idle-timeout-s", float, d.idle_timeout_s, "seconds before a silent connection "
         "is closed"),
    ]  # fmt: skip
    for flag, kind, default, what in limit_flags:
        serve.add_argument(flag, type=kind, default=default, help=f"{what} (default {default})")
    serve.set_defaults(func=_serve)


def _add_view(
    sub: argparse._SubParsersAction,
    load_corrections: Optional[Callable[[list[Path], list[str]], Corrections]],
) -> None:
    view = sub.add_parser("view", help="save PNG frames of a short episode")
    view.add_argument("--seed", type=int, default=0, help="world seed")
    view.add_argument("--steps", type=int, default=200, help="ticks to run")
    view.add_argument("--frames", type=int, default=6, help="frames to save")
    view.add_argument("--out", default="minecraft_frames", help="output directory")
    view.add_argument("--width", type=int, default=96, help="frame width")
    view.add_argument("--height", type=int, default=64, help="frame height")
    view.add_argument("--scale", type=int, default=4, help="upscaling of saved PNGs")
    view.add_argument(
        "--gif", default="", help="run the obtain-diamond tree instead and write this GIF"
    )
    view.add_argument("--every", type=int, default=10, help="GIF: one frame every N steps")
    view.add_argument(
        "--ticks-per-step", type=int, default=1, help="GIF: ticks each decision is held"
    )
    view.add_argument(
        "--controller", action="append", default=[], metavar="RUN_DIR",
        help="GIF: a trained run correcting the leaf it trained for (repeatable)",
    )  # fmt: skip
    view.add_argument(
        "--travel-while", action="append", default=[], metavar="ACTIVITY",
        help="GIF: the travel correction walks only in this activity's walks, e.g. "
             "searching (repeatable; default: every walk)",
    )  # fmt: skip
    view.set_defaults(func=_view, load_corrections=load_corrections)


def main(argv: Optional[list[str]] = None) -> int:
    """Entry point for ``python -m minecraft.cli minecraft ...``."""
    parser = argparse.ArgumentParser(prog="graft")
    sub = parser.add_subparsers(dest="command", required=True)
    add_minecraft_commands(sub)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    sys.exit(main())
