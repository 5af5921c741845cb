"""The chaos benchmark's refusals: 10,000 refused requests of each kind a replay server
refuses, most carrying a 1 MiB field, against one server process; its RSS before, at its
peak while they arrive, and after, once the server has handed freed memory back: after
`QUIET_PASSES` of its memory passes (every `TRIM_EVERY_S` after refused calls), counted
by its metrics, have ended since the last request was answered.
"""

from __future__ import annotations

import threading
import time
import urllib.request
from collections.abc import Callable
from typing import Any

import grpc
from chaos_ledger import free_port  # bench/, beside this script
from procfs import rss_mib

from graft.replay_host.process import ReplayProcess
from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.server.allocator import QUIET_PASSES, TRIM_EVERY_S

MIB = "n" * 2**20
FLAT = 1.10
"""The bound: RSS after a kind's requests at most this times RSS before them."""
SIGNATURE = {"x": {"dtype": "int64", "shape": []}}

Refusal = Callable[[replay_pb2_grpc.ReplayServiceStub], Any]

REFUSALS: dict[str, Refusal] = {
    "Insert, 1 MiB table name": lambda s: s.Insert(iter([replay_pb2.InsertRequest(table=MIB)])),
    "Insert, 1 MiB writer id": lambda s: s.Insert(
        iter([replay_pb2.InsertRequest(table="t", writer_id=MIB, sequence=1)])
    ),
    "Insert, 1 MiB payload, not msgpack": lambda s: s.Insert(
        iter([replay_pb2.InsertRequest(table="t", batch=b"\xc1" * 2**20)])
    ),
    "Insert, unknown table": lambda s: s.Insert(iter([replay_pb2.InsertRequest(table="u")])),
    "Sample, 1 MiB table name": lambda s: list(
        s.Sample(iter([replay_pb2.SampleRequest(table=MIB, batch_size=1)]))
    ),
    "Sample, batch_size over the message limit": lambda s: list(
        s.Sample(iter([replay_pb2.SampleRequest(table="t", batch_size=2**31 - 1)]))
    ),
    "UpdatePriorities, 1 MiB table name": lambda s: s.UpdatePriorities(
        replay_pb2.UpdatePrioritiesRequest(table=MIB)
    ),
}


def _send(address: str, refuse: Refusal, n: int, *, threads: int = 4) -> set[str]:
    """Sends `n` copies of one refused request over `threads` channels; the status codes."""
    codes: set[str] = set()

    def run(count: int) -> None:
        with grpc.insecure_channel(address) as channel:
            stub = replay_pb2_grpc.ReplayServiceStub(channel)
            for _ in range(count):
                try:
                    refuse(stub)
                    codes.add("OK")
                except grpc.RpcError as error:
                    codes.add(error.code().name)

    workers = [threading.Thread(target=run, args=(n // threads,)) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    return codes


def _memory_passes(metrics_port: int) -> int:
    """The server's memory passes so far (`graft_replay_memory_passes_total`)."""
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10) as r:
        for line in r.read().decode().splitlines():
            if line.startswith("graft_replay_memory_passes_total "):
                return int(float(line.split()[1]))
    raise RuntimeError("the server's metrics have no graft_replay_memory_passes_total")


def _settled_rss_mib(pid: int, metrics_port: int) -> float:
    """RSS once the server has made `QUIET_PASSES` memory passes since this call: what the
    last requests freed is back with the OS, however loaded the machine (a pass frees what
    the one before collected: gRPC frees a collected call's buffers a moment later)."""
    done = _memory_passes(metrics_port) + QUIET_PASSES
    deadline = time.monotonic() + 60 * TRIM_EVERY_S
    while _memory_passes(metrics_port) < done:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the server made no {QUIET_PASSES} memory passes in 60 periods")
        time.sleep(0.1 * TRIM_EVERY_S)
    return rss_mib(pid)


def _send_watching(address: str, refuse: Refusal, n: int, pid: int) -> tuple[set[str], float]:
    """`_send`, and the highest RSS read (every 20 ms) while the requests arrive."""
    peak = [rss_mib(pid)]
    done = threading.Event()

    def watch() -> None:
        while not done.wait(0.02):
            peak[0] = max(peak[0], rss_mib(pid))

    watcher = threading.Thread(target=watch)
    watcher.start()
    try:
        return _send(address, refuse, n), peak[0]
    finally:
        done.set()
        watcher.join()


def refused_requests(n: int, *, warm_up: int = 200) -> dict[str, Any]:
    """`n` refused requests of each kind in REFUSALS, after `warm_up` of each (the
    allocator's arenas and gRPC's buffers reach their working size); RSS per kind."""
    tables = [{"name": "t", "max_size": 1000, "signature": SIGNATURE}]
    port = free_port()
    with ReplayProcess(tables, extra_args=["--metrics-port", str(port)]) as server:
        pid = server.process.pid
        started = rss_mib(pid)
        for refuse in REFUSALS.values():
            _send(server.address, refuse, warm_up)
        warm = _settled_rss_mib(pid, port)
        kinds = []
        for name, refuse in REFUSALS.items():
            before = rss_mib(pid)
            codes, peak = _send_watching(server.address, refuse, n, pid)
            after = _settled_rss_mib(pid, port)
            kinds.append(
                {"kind": name, "codes": sorted(codes), "rss": (before, after), "peak": peak}
            )
        return {"n": n, "started": started, "warm": warm, "end": rss_mib(pid), "kinds": kinds}
