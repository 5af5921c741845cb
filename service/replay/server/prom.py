"""Prometheus metrics of a replay server, on their own registry (several servers may share
a process in tests) and served over HTTP."""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, start_http_server
from prometheus_client.core import CounterMetricFamily, Metric
from prometheus_client.registry import Collector

from service.replay.server.allocator import FreedMemory
from service.replay.server.store import ReplayCore
from service.replay.server.table import Table


class ReplayMetrics:
    """RPC latency, bytes in/out, and per-table figures read live from the core: the
    `RpcMeter` of a server with a metrics port."""

    def __init__(self, core: ReplayCore, freed: FreedMemory) -> None:
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
            "graft_replay_table_bytes": (
                "Bytes of table storage at max_size", lambda t: t.bytes_in_memory),
            "graft_replay_table_bytes_used": (
                "Bytes the stored items fill", lambda t: t.bytes_used),
            "graft_replay_insert_blocked_seconds": (
                "Time inserts waited on the rate limiter", lambda t: t.stats.insert_blocked_s),
            "graft_replay_sample_blocked_seconds": (
                "Time samples waited on the rate limiter", lambda t: t.stats.sample_blocked_s),
        }  # fmt: skip
        for name, (help_text, read) in per_table.items():
            gauge = Gauge(name, help_text, ["table"], registry=r)
            for table in core.tables.values():
                gauge.labels(table.name).set_function(functools.partial(read, table))
        if core.memory_budget is not None:
            Gauge(
                "graft_replay_memory_budget_bytes",
                "What the tables may fill together",
                registry=r,
            ).set(core.memory_budget.bytes)
        r.register(_DurabilityCollector(core))
        r.register(_FreedMemoryCollector(freed))

    def refused(self, code: str) -> None:
        self.errors.labels(code).inc()

    def received(self, nbytes: int) -> None:
        self.bytes_in.inc(nbytes)

    def sent(self, nbytes: int) -> None:
        self.bytes_out.inc(nbytes)

    def handled(self, method: str, seconds: float) -> None:
        self.rpc_latency.labels(method).observe(seconds)

    def serve(self, port: int, host: str = "127.0.0.1") -> int:
        """Starts the /metrics HTTP endpoint; returns the bound port."""
        server, _ = start_http_server(port, addr=host, registry=self.registry)
        return int(server.server_port)


class _DurabilityCollector(Collector):
    """Counters of the checkpoint folder, read from the core when scraped."""

    def __init__(self, core: ReplayCore) -> None:
        self._core = core

    def collect(self) -> Iterator[Metric]:
        d = self._core.durability
        for name, help_text, value in (
            ("graft_replay_checkpoints", "Checkpoints written", d.checkpoints),
            ("graft_replay_checkpoint_failures", "Checkpoints that failed (e.g. disk full); "
             "the next period retries", d.checkpoint_failures),
            ("graft_replay_log_append_failures", "Inserts refused because the write-ahead "
             "log append failed", d.log_append_failures),
            ("graft_replay_unlogged_samples", "Items sampled while the write-ahead log could "
             "not record it (a restart before the next checkpoint would not count them)",
             d.unlogged_samples),
            ("graft_replay_damaged_log_records", "Log records skipped at start-up: their "
             "checksum failed, or their fields or batch did not decode", d.damaged_log_records),
            ("graft_replay_damaged_checkpoints", "Checkpoints found unreadable at start-up",
             d.damaged_checkpoints),
        ):  # fmt: skip
            yield CounterMetricFamily(name, help_text, value=value)


class _FreedMemoryCollector(Collector):
    """The passes that handed what refused and aborted calls freed back to the OS."""

    def __init__(self, freed: FreedMemory) -> None:
        self._freed = freed

    def collect(self) -> Iterator[Metric]:
        yield CounterMetricFamily(
            "graft_replay_memory_passes",
            "Garbage collections and malloc_trims made after refused or aborted calls",
            value=self._freed.passes,
        )
