"""The chaos benchmark's load: 64 idle sample streams + 16 writers in 4 processes against one
replay server, with health checks alongside; inserts and checks answered, latency, RSS.
"""

from __future__ import annotations

import multiprocessing as mp
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import grpc
import numpy as np
from chaos_ledger import server, table  # bench/, beside this script
from grpc_health.v1 import health_pb2, health_pb2_grpc
from procfs import rss_mib

from service.replay._proto import replay_pb2
from service.replay.client import ReplayClient
from service.replay.codec import encode_batch


def _load_process(address: str, threads: int, seconds: float, out: Any) -> None:
    """`threads` writers inserting with a 5 s deadline; sends (latencies, error codes)."""
    client = ReplayClient(address)
    payload = encode_batch({"x": np.arange(64, dtype=np.int64)})
    latencies: list[float] = []
    errors: list[str] = []
    lock = threading.Lock()
    end = time.monotonic() + seconds

    def write() -> None:
        request = replay_pb2.InsertRequest(table="t", batch=payload)
        while time.monotonic() < end:
            start = time.perf_counter()
            try:
                client.stub.Insert(iter([request]), timeout=5.0)
                with lock:
                    latencies.append(time.perf_counter() - start)
            except grpc.RpcError as error:
                with lock:
                    errors.append(error.code().name)
            time.sleep(0.01)

    workers = [threading.Thread(target=write) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    out.put((latencies, errors))


def idle_streams(seconds: float, *, streams: int = 64, writers: int = 16) -> dict[str, Any]:
    """`streams` sample streams waiting on a table that never fills while `writers` insert
    for `seconds` and a health check is made every 0.1 s; answers, latencies and RSS."""
    with tempfile.TemporaryDirectory(prefix="chaos-idle-") as tmp:
        folder = Path(tmp)
        tables = [
            table({"kind": "min_size", "min_size": 1}),
            # Never fills: a sample stream on it waits for good, like a paused learner.
            {**table({"kind": "min_size", "min_size": 1000}, "idle"), "max_size": 1000},
        ]
        s = server(tables, folder)
        client = ReplayClient(s.address)
        close = threading.Event()

        def requests() -> Iterator[replay_pb2.SampleRequest]:
            yield replay_pb2.SampleRequest(table="idle", batch_size=1, num_batches=1)
            close.wait()

        calls = [client.stub.Sample(requests()) for _ in range(streams)]
        time.sleep(1.0)
        rss_start = rss_mib(s.process.pid)
        ctx = mp.get_context("spawn")
        out = ctx.Queue()
        procs = [
            ctx.Process(target=_load_process, args=(s.address, writers // 4, seconds, out))
            for _ in range(4)
        ]
        for p in procs:
            p.start()
        health = health_pb2_grpc.HealthStub(grpc.insecure_channel(s.address))
        checks: list[bool] = []
        end = time.monotonic() + seconds + 5.0  # the writer processes take a while to start
        next_report = time.monotonic() + 10.0
        while time.monotonic() < end:
            if time.monotonic() >= next_report:
                next_report += 10.0
                print(f"    {sum(checks)}/{len(checks)} health checks answered, "
                      f"{end - time.monotonic():.0f} s left", flush=True)  # fmt: skip
            try:
                health.Check(health_pb2.HealthCheckRequest(), timeout=2.0)
                checks.append(True)
            except grpc.RpcError:
                checks.append(False)
            time.sleep(0.1)
        results = [out.get(timeout=120) for _ in procs]
        for p in procs:
            p.join(60)
        rss_end = rss_mib(s.process.pid)
        close.set()
        for call in calls:
            call.cancel()
        s.stop()
    latencies = np.array([x for lat, _ in results for x in lat])
    errors = [e for _, errs in results for e in errs]
    return {
        "inserts answered": len(latencies),
        "inserts failed": len(errors),
        "failure codes": sorted(set(errors)),
        "health answered": sum(checks),
        "health checks": len(checks),
        "p50 ms": 1e3 * float(np.percentile(latencies, 50)) if len(latencies) else float("nan"),
        "p99 ms": 1e3 * float(np.percentile(latencies, 99)) if len(latencies) else float("nan"),
        "rss": (rss_start, rss_end),
    }
