"""Prometheus metrics of a replay server, on their own registry (several servers may share
a process in tests) and served over HTTP."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Optional

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server

from service.replay.server.store import ReplayCore
from service.replay.server.table import Table


class ReplayMetrics:
    """RPC latency, bytes in/out, and per-table figures read live from the core."""

    def __init__(self, core: ReplayCore) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.rpc_latency = Histogram(
            "graft_replay_rpc_seconds", "RPC handling time", ["method"], registry=r,
            buckets=(1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0, 3.0, 10.0),
        )  # fmt: skip
        self.bytes_in = Counter("graft_replay_bytes_in", "Payload bytes received", registry=r)
        self.bytes_out = Counter("graft_replay_bytes_out", "Payload bytes sent", registry=r)
        self.errors = Counter(
            "graft_replay_errors", "RPCs refused, by status", ["code"], registry=r
        )
        per_table: dict[str, tuple[str, Callable[[Table], float]]] = {
            "graft_replay_table_size": ("Items stored", lambda t: t.size),
            "graft_replay_table_inserts": ("Items ever inserted", lambda t: t.stats.inserts),
            "graft_replay_table_samples": ("Items ever sampled", lambda t: t.stats.samples),
            "graft_replay_table_bytes": ("Bytes of table storage", lambda t: t.bytes_in_memory),
            "graft_replay_insert_blocked_seconds": (
                "Time inserts waited on the rate limiter", lambda t: t.stats.insert_blocked_s),
            "graft_replay_sample_blocked_seconds": (
                "Time samples waited on the rate limiter", lambda t: t.stats.sample_blocked_s),
        }  # fmt: skip
        for name, (help_text, read) in per_table.items():
            gauge = Gauge(name, help_text, ["table"], registry=r)
            for table in core.tables.values():
                gauge.labels(table.name).set_function(functools.partial(read, table))

    def serve(self, port: int, host: str = "127.0.0.1") -> Optional[int]:
        """Starts the /metrics HTTP endpoint; returns the bound port."""
        server, _ = start_http_server(port, addr=host, registry=self.registry)
        return int(server.server_port)
