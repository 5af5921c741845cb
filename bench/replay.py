"""Benchmark: the replay server over loopback against an in-process numpy ring buffer.

For Pendulum-shaped transitions (obs 3, action 1, reward, terminated, truncated,
next obs 3, log-likelihood, version) and a Minecraft-shaped row (obs of 3,400 float32):
insert throughput from one writer and from 16 concurrent writer processes, sample
throughput in batches of 256 with prefetch, p50/p99 sample latency, and the server's
memory growth against the configured size of its contents. With `--durable` the server
keeps a checkpoint folder: every insert and every sampled batch is written to its log.

    python bench/replay.py [--quick] [--durable] [--shape pendulum]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient

PREFETCH = (8, 32)
"""Sample streams measured: batches each keeps in flight (`prefetch`, the learner's knob;
half of them per response). A window of 8 batches is 2 ms of sampling at 1M items/s, so
each thread's wake-up on a loaded machine stalls it; 32 rides them out."""


@dataclass(frozen=True)
class Shape:
    name: str
    obs: int
    max_size: int
    insert_batch: int
    total_inserts: int

    def signature(self) -> dict:
        obs = {"dtype": "float32", "shape": [self.obs]}
        return {
            "obs": obs,
            "action": {"dtype": "float32", "shape": [1]},
            "reward": {"dtype": "float32", "shape": []},
            "terminated": {"dtype": "bool", "shape": []},
            "truncated": {"dtype": "bool", "shape": []},
            "next_obs": obs,
            "log_prob": {"dtype": "float32", "shape": []},
            "policy_version": {"dtype": "int64", "shape": []},
        }

    def batch(self, n: int, seed: int = 0) -> dict[str, np.ndarray]:
        rng = np.random.default_rng(seed)
        return {
            "obs": rng.random((n, self.obs), dtype=np.float32),
            "action": rng.random((n, 1), dtype=np.float32),
            "reward": rng.random(n, dtype=np.float32),
            "terminated": np.zeros(n, bool),
            "truncated": rng.random(n) < 0.005,
            "next_obs": rng.random((n, self.obs), dtype=np.float32),
            "log_prob": rng.random(n, dtype=np.float32),
            "policy_version": np.zeros(n, np.int64),
        }

    @property
    def item_bytes(self) -> int:
        return 2 * 4 * self.obs + 4 + 4 + 1 + 1 + 4 + 8


class NumpyRing:
    """The ceiling: the same insert and uniform-sample work on in-process arrays."""

    def __init__(self, shape: Shape) -> None:
        self.columns = {
            k: np.zeros((shape.max_size, *v.shape[1:]), v.dtype) for k, v in shape.batch(1).items()
        }
        self.size, self.next, self.cap = 0, 0, shape.max_size
        self.rng = np.random.default_rng(0)

    def insert(self, batch: dict[str, np.ndarray]) -> None:
        n = len(batch["obs"])
        rows = (self.next + np.arange(n)) % self.cap
        for k, a in self.columns.items():
            a[rows] = batch[k]
        self.next += n
        self.size = min(self.size + n, self.cap)

    def sample(self, b: int) -> dict[str, np.ndarray]:
        rows = self.rng.integers(0, self.size, b)
        return {k: a[rows] for k, a in self.columns.items()}


def rss_bytes(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


def _writer_process(address: str, shape: Shape, batches: int, seed: int, start, done) -> None:
    client = ReplayClient(address)
    batch = shape.batch(shape.insert_batch, seed)
    start.wait()
    for _ in range(batches):
        client.insert("t", batch)
    done.put(time.perf_counter())


def measure(shape: Shape, quick: bool, durable: bool = False) -> dict[str, dict[str, float]]:
    batch = shape.batch(shape.insert_batch)
    n_batches = shape.total_inserts // shape.insert_batch
    sample_batches = 1000 if quick else 10_000  # about 2 s of sampling on this machine
    results: dict[str, dict[str, float]] = {"server": {}, "numpy ring": {}}

    ring = NumpyRing(shape)
    t = time.perf_counter()
    for _ in range(n_batches):
        ring.insert(batch)
    results["numpy ring"]["insert 1 writer /s"] = (
        n_batches * shape.insert_batch / (time.perf_counter() - t)
    )
    lat = []
    t = time.perf_counter()
    for _ in range(sample_batches):
        s = time.perf_counter()
        ring.sample(256)
        lat.append(time.perf_counter() - s)
    ring_rate = sample_batches * 256 / (time.perf_counter() - t)
    for prefetch in PREFETCH:  # the same ring rate in each sampling column
        results["numpy ring"][f"sample /s, prefetch {prefetch}"] = ring_rate
    results["numpy ring"]["p50 ms"] = 1e3 * float(np.percentile(lat, 50))
    results["numpy ring"]["p99 ms"] = 1e3 * float(np.percentile(lat, 99))

    table = [{"name": "t", "max_size": shape.max_size, "signature": shape.signature()}]
    folder = tempfile.TemporaryDirectory(prefix="graft-bench-replay-")
    extra = ["--max-message-mb", "256"]
    if durable:  # no periodic checkpoint: every figure includes the log's cost, none a snapshot's
        extra += ["--checkpoint-dir", folder.name, "--checkpoint-every-s", "0"]
    with folder, ReplayProcess(table, extra_args=extra) as server:
        client = ReplayClient(server.address, max_message_bytes=256 * 2**20)
        client.info()
        rss_empty = rss_bytes(server.process.pid)
        r = results["server"]
        t = time.perf_counter()
        for _ in range(n_batches):
            client.insert("t", batch)
        r["insert 1 writer /s"] = n_batches * shape.insert_batch / (time.perf_counter() - t)

        # Fill the table completely, then measure memory against its configured contents.
        while client.info()[0].size < shape.max_size:
            client.insert("t", batch)
        content = shape.max_size * shape.item_bytes
        r["memory / contents"] = (rss_bytes(server.process.pid) - rss_empty) / content

        ctx = mp.get_context("spawn")
        start, done = ctx.Event(), ctx.Queue()
        per_writer = max(n_batches // 16, 2)
        writers = [
            ctx.Process(
                target=_writer_process, args=(server.address, shape, per_writer, i, start, done)
            )
            for i in range(16)
        ]
        for w in writers:
            w.start()
        time.sleep(3.0)  # let every writer connect before the start signal
        t = time.perf_counter()
        start.set()
        finished = max(done.get(timeout=600) for _ in writers)
        for w in writers:
            w.join()
        r["insert 16 writers /s"] = 16 * per_writer * shape.insert_batch / (finished - t)

        for prefetch in PREFETCH:
            stream = client.sample_stream("t", 256, prefetch=prefetch)
            next(stream)
            t = time.perf_counter()
            for _ in range(sample_batches):
                next(stream)
            r[f"sample /s, prefetch {prefetch}"] = sample_batches * 256 / (time.perf_counter() - t)
            stream.close()

        # Latency: one batch in flight, so each wait is a full request-to-batch round trip.
        stream = client.sample_stream("t", 256, prefetch=1)
        lat = []
        for _ in range(min(sample_batches, 1000)):
            s = time.perf_counter()
            next(stream)
            lat.append(time.perf_counter() - s)
        stream.close()
        r["p50 ms"] = 1e3 * float(np.percentile(lat, 50))
        r["p99 ms"] = 1e3 * float(np.percentile(lat, 99))
        client.close()
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer batches (a smoke run)")
    parser.add_argument(
        "--durable", action="store_true", help="the server logs inserts and samples to disk"
    )
    parser.add_argument("--shape", help="only the shapes whose name starts with this")
    args = parser.parse_args()
    scale = 10 if args.quick else 1
    shapes = [
        Shape(
            "pendulum (46 B/item)",
            obs=3,
            max_size=1_000_000,
            insert_batch=1024,
            total_inserts=2_000_000 // scale,
        ),
        Shape(
            "minecraft (27 KB/item)",
            obs=3400,
            max_size=10_000,
            insert_batch=64,
            total_inserts=40_000 // scale,
        ),
    ]
    columns = [
        "insert 1 writer /s",
        "insert 16 writers /s",
        *(f"sample /s, prefetch {p}" for p in PREFETCH),
        "p50 ms",
        "p99 ms",
        "memory / contents",
        "sample, server / ring",
    ]
    print("| shape | store | " + " | ".join(columns) + " |")
    print("|---|---|" + "---|" * len(columns))
    for shape in shapes:
        if args.shape and not shape.name.startswith(args.shape):
            continue
        results = measure(shape, args.quick, args.durable)
        server, ring = results["server"], results["numpy ring"]
        deepest = f"sample /s, prefetch {PREFETCH[-1]}"
        server["sample, server / ring"] = server[deepest] / ring[deepest]
        for store, figures in results.items():
            cells = []
            for c in columns:
                v = figures.get(c)
                cells.append("-" if v is None else f"{v:,.0f}" if v > 100 else f"{v:.2f}")
            print(f"| {shape.name} | {store} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
