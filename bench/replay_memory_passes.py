"""Benchmark: what the replay server's memory passes (a full garbage collection and
`malloc_trim`, service/replay/server/allocator.py) cost a large Minecraft-shaped table.

Four servers side by side, each holding `--items` image items (two 64x64x3 uint8 frames
each, 24 KiB): `every second` makes a pass each second whatever happens, over every object
(what the server did before); `after refusals` is the server's own (objects alive at start
frozen, passes only after refused or aborted calls), here with no refusals; `after
refusals, refused 2/s` the same with two refused requests a second, so it makes a pass
each second; `none` makes no pass. Rounds alternate between them (the order rotated each
round): for `--window-s` seconds 2 writers insert batches of 16 items and 1 reader draws
batches of 32, each call a round trip. Per server: call latency (p50, p99, max), calls per
second, the server's CPU seconds per second, and its full collections (the interpreter's
own included) and trims: count, mean and longest, timed inside the server.

    python bench/replay_memory_passes.py [--quick] [--items N] [--rounds R] [--window-s S]
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Optional

import grpc
import numpy as np
from procfs import cpu_seconds  # bench/, beside this script

from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.client import ReplayClient

FRAME = (64, 64, 3)
SIGNATURE = {
    "obs": {"dtype": "uint8", "shape": list(FRAME)},
    "next_obs": {"dtype": "uint8", "shape": list(FRAME)},
    "action": {"dtype": "float32", "shape": [3]},
    "reward": {"dtype": "float32", "shape": []},
    "terminated": {"dtype": "bool", "shape": []},
    "truncated": {"dtype": "bool", "shape": []},
}
POLICIES = ("every second", "after refusals", "after refusals, refused 2/s", "none")


def batch(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "obs": rng.integers(0, 256, (n, *FRAME), dtype=np.uint8),
        "next_obs": rng.integers(0, 256, (n, *FRAME), dtype=np.uint8),
        "action": rng.random((n, 3), dtype=np.float32),
        "reward": rng.random(n, dtype=np.float32),
        "terminated": np.zeros(n, bool),
        "truncated": rng.random(n) < 0.01,
    }


# ------------------------------------------------------------------ the server side


def _serve(policy: str, passes_file: str, argv: list[str]) -> None:
    """Runs `graft replay serve argv` with the memory passes of `policy`, appending each
    full collection's and each trim's duration (ms) to `passes_file`."""
    from graft.cli.replay import main
    from service.replay.server import allocator

    out = open(passes_file, "a", buffering=1)
    started: list[float] = []

    def on_gc(phase: str, info: dict[str, int]) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            started.append(time.perf_counter())
        elif started:
            out.write(f"gc {1e3 * (time.perf_counter() - started.pop()):.3f}\n")

    gc.callbacks.append(on_gc)
    trim = ctypes.CDLL(None).malloc_trim
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int

    def timed_trim(pad: int) -> int:
        start = time.perf_counter()
        result: int = trim(pad)
        out.write(f"trim {1e3 * (time.perf_counter() - start):.3f}\n")
        return result

    allocator._malloc_trim = lambda: timed_trim  # type: ignore[assignment]

    def every_second(self: allocator.FreedMemory, stop: threading.Event) -> None:
        while not stop.wait(1.0):  # the passes before: unconditional, over every object
            gc.collect()
            timed_trim(0)

    def none(self: allocator.FreedMemory, stop: threading.Event) -> None:
        stop.wait()

    replace: dict[str, Callable[[allocator.FreedMemory, threading.Event], None]] = {
        "every second": every_second,
        "none": none,
    }
    if policy in replace:
        allocator.FreedMemory.run = replace[policy]  # type: ignore[method-assign]
    main(argv)


class Server:
    """A replay server process with one policy's memory passes."""

    def __init__(self, policy: str, items: int, folder: Path) -> None:
        self.policy = policy
        slug = policy.replace(" ", "-").replace(",", "").replace("/", "per")
        config, ready = folder / f"{slug}.json", folder / f"{slug}.ready"
        self.passes_file = folder / f"{slug}.passes"
        table = {"name": "t", "max_size": items, "signature": SIGNATURE}
        config.write_text(json.dumps({"tables": [table]}))
        command = [sys.executable, __file__, "--serve", policy, str(self.passes_file), "serve"]
        command += ["--config", str(config), "--port", "0", "--ready-file", str(ready)]
        log = folder / f"{slug}.log"
        with open(log, "wb") as out:
            self.process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
        while not ready.exists():
            if self.process.poll() is not None:
                tail = log.read_text(errors="replace").strip().splitlines()[-1:]
                raise RuntimeError(f"the '{policy}' server exited during start-up: {tail}")
            time.sleep(0.05)
        self.address: str = json.loads(ready.read_text())["address"]

    def passes(self) -> dict[str, list[float]]:
        """Each full collection's and trim's duration (ms) so far."""
        found: dict[str, list[float]] = {"gc": [], "trim": []}
        for line in self.passes_file.read_text().splitlines():
            kind, ms = line.split()
            found[kind].append(float(ms))
        return found

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(30)


# ------------------------------------------------------------------ the load


def _load(server: Server, seconds: float, seed: int) -> dict[str, Any]:
    """2 writers and 1 reader for `seconds`, plus 2 refused requests a second where the
    policy asks for them; each call's latency (s) and the server's CPU seconds."""
    stop = threading.Event()
    latencies: dict[str, list[float]] = {"insert": [], "sample": []}
    errors: list[BaseException] = []

    def writer(k: int) -> None:
        client = ReplayClient(server.address, writer_id=f"w{seed}-{k}")
        rows = batch(16, seed * 10 + k)
        while not stop.is_set():
            start = time.perf_counter()
            client.insert("t", rows)
            latencies["insert"].append(time.perf_counter() - start)
        client.close()

    def reader() -> None:
        with grpc.insecure_channel(server.address) as channel:
            stub = replay_pb2_grpc.ReplayServiceStub(channel)
            request = replay_pb2.SampleRequest(table="t", batch_size=32, num_batches=1)
            while not stop.is_set():
                start = time.perf_counter()
                (response,) = list(stub.Sample(iter([request])))
                latencies["sample"].append(time.perf_counter() - start)
                assert response.num_batches == 1

    def refuser() -> None:
        with grpc.insecure_channel(server.address) as channel:
            stub = replay_pb2_grpc.ReplayServiceStub(channel)
            while not stop.wait(0.5):
                try:
                    stub.Insert(iter([replay_pb2.InsertRequest(table="no such table")]))
                except grpc.RpcError as error:
                    assert error.code() == grpc.StatusCode.NOT_FOUND

    def guarded(run: Callable[[], None]) -> Callable[[], None]:
        def call() -> None:
            try:
                run()
            except BaseException as error:
                errors.append(error)
                stop.set()

        return call

    jobs = [lambda k=k: writer(k) for k in range(2)] + [reader]
    if "refused" in server.policy:
        jobs.append(refuser)
    threads = [threading.Thread(target=guarded(job)) for job in jobs]
    before = {kind: len(done) for kind, done in server.passes().items()}
    cpu = cpu_seconds(server.process.pid)
    for t in threads:
        t.start()
    stop.wait(seconds)
    stop.set()
    for t in threads:
        t.join()
    cpu = cpu_seconds(server.process.pid) - cpu
    if errors:
        raise errors[0]
    passes = {kind: done[before[kind] :] for kind, done in server.passes().items()}
    return {**latencies, **passes, "cpu s": cpu}


def _fill(server: Server, items: int) -> None:
    client = ReplayClient(server.address, writer_id="fill")
    rows = batch(64, 0)
    for _ in range(-(-items // 64)):
        client.insert("t", rows)
    client.close()


def _row(policy: str, runs: list[dict[str, Any]], seconds: float) -> str:
    cells = [policy]
    for kind in ("insert", "sample"):
        ms = 1e3 * np.concatenate([r[kind] for r in runs])
        cells += [f"{np.percentile(ms, 50):.1f}", f"{np.percentile(ms, 99):.1f}"]
        cells += [f"{ms.max():.0f}", f"{len(ms) / seconds:,.0f}"]
    cells.append(f"{sum(r['cpu s'] for r in runs) / seconds:.2f}")
    for kind in ("gc", "trim"):
        done = [ms for r in runs for ms in r[kind]]
        cells.append(f"{len(done)}, {np.mean(done):.1f} / {max(done):.1f}" if done else "0")
    return "| " + " | ".join(cells) + " |"


def main(argv: Optional[list[str]] = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smoke run (well under a minute)")
    parser.add_argument("--items", type=int, default=None, help="items per table (20,000)")
    parser.add_argument("--rounds", type=int, default=None, help="rounds of each server (3)")
    parser.add_argument("--window-s", type=float, default=None, help="load per round (10 s)")
    args = parser.parse_args(argv)
    items = args.items or (2_000 if args.quick else 20_000)
    rounds = args.rounds or (1 if args.quick else 3)
    window = args.window_s or (3.0 if args.quick else 10.0)
    print(
        f"4 servers, {items:,} items each ({items * 24_600 / 2**20:,.0f} MiB), {rounds} rounds "
        f"of {window:.0f} s each, 2 writers (16 items a call) + 1 reader (32 a call)",
        flush=True,
    )
    with tempfile.TemporaryDirectory(prefix="graft-bench-passes-") as folder:
        servers = [Server(p, items, Path(folder)) for p in POLICIES]
        try:
            for s in servers:
                _fill(s, items)
            runs: dict[str, list[dict[str, Any]]] = {s.policy: [] for s in servers}
            for r in range(rounds):
                for s in servers[r % len(servers) :] + servers[: r % len(servers)]:
                    runs[s.policy].append(_load(s, window, seed=r))
                print(f"... round {r + 1} of {rounds}", flush=True)
            seconds = rounds * window
            print()
            print(
                "| passes | insert p50 ms | p99 | max | inserts/s | sample p50 ms | p99 | max "
                "| samples/s | server CPU s/s | full collections (n, mean / max ms) "
                "| trims (n, mean / max ms) |"
            )
            print("|---|---|---|---|---|---|---|---|---|---|---|---|")
            for s in servers:
                print(_row(s.policy, runs[s.policy], seconds))
        finally:
            for s in servers:
                s.stop()


if __name__ == "__main__":
    if len(sys.argv) > 3 and sys.argv[1] == "--serve":
        _serve(sys.argv[2], sys.argv[3], sys.argv[4:])
    else:
        main()
