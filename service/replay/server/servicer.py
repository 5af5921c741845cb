"""The replay gRPC server: a thin servicer over ReplayCore, plus its process entry point."""

from __future__ import annotations

import hmac
import json
import logging
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from concurrent import futures
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, Optional

import grpc
import numpy as np
from grpc_health.v1 import health, health_pb2, health_pb2_grpc

from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.codec import (
    DEFAULT_MAX_BYTES,
    TOKEN_METADATA_KEY,
    CodecError,
    PayloadTooLarge,
    decode_batch,
    encode_batch,
)
from service.replay.server.durability import StorageError
from service.replay.server.prom import ReplayMetrics
from service.replay.server.signature import SignatureError
from service.replay.server.store import ReplayCore, UnknownTable
from service.replay.server.table import RateLimitTimeout

log = logging.getLogger(__name__)

SERVICE_NAME = "graft.replay.v1.ReplayService"
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})


class InsecureBindError(ValueError):
    """Binding a non-loopback address without a token or an explicit opt-out."""


_STATUS_OF = (
    (PayloadTooLarge, grpc.StatusCode.RESOURCE_EXHAUSTED),
    (UnknownTable, grpc.StatusCode.NOT_FOUND),
    (RateLimitTimeout, grpc.StatusCode.DEADLINE_EXCEEDED),
    (StorageError, grpc.StatusCode.UNAVAILABLE),  # e.g. a full disk; a resend may succeed
    ((CodecError, SignatureError, ValueError), grpc.StatusCode.INVALID_ARGUMENT),
)


class ReplayServicer(replay_pb2_grpc.ReplayServiceServicer):
    """Decode, validate, call the core, encode. Nothing else lives here."""

    def __init__(
        self,
        core: ReplayCore,
        metrics: ReplayMetrics,
        *,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
    ) -> None:
        self.core = core
        self.metrics = metrics
        self.max_message_bytes = max_message_bytes

    def _abort(self, context: grpc.ServicerContext, error: Exception) -> NoReturn:
        """Maps a core exception to the status a client can act on; re-raises the unknown."""
        for kinds, code in _STATUS_OF:
            if isinstance(error, kinds):
                self.metrics.errors.labels(code.name).inc()
                context.abort(code, str(error))
        raise error

    @staticmethod
    def _timeout(request_timeout: float, context: grpc.ServicerContext) -> Optional[float]:
        """The tighter of the request's own timeout and the RPC deadline."""
        limits = [t for t in (request_timeout or None, context.time_remaining()) if t is not None]
        return min(limits) if limits else None

    def Insert(  # noqa: N802 (gRPC method name)
        self, request_iterator: Iterator[replay_pb2.InsertRequest], context: grpc.ServicerContext
    ) -> replay_pb2.InsertResponse:
        stored = dropped = 0
        acked: dict[str, int] = {}
        for request in request_iterator:
            start = time.perf_counter()
            self.metrics.bytes_in.inc(len(request.batch))
            try:
                result = self.core.insert(
                    request.table,
                    decode_batch(request.batch, max_bytes=self.max_message_bytes),
                    writer_id=request.writer_id,
                    sequence=request.sequence,
                    timeout=self._timeout(request.timeout_s, context),
                    payload=request.batch,
                )
            except Exception as error:
                self._abort(context, error)
            if result is None:
                dropped += 1
            else:
                stored += result
            if request.writer_id:
                acked[request.writer_id] = self.core.acked.get(request.writer_id, 0)
            self.metrics.rpc_latency.labels("Insert").observe(time.perf_counter() - start)
        return replay_pb2.InsertResponse(
            items_inserted=stored, batches_dropped_as_duplicates=dropped, acked_sequence=acked
        )

    def Sample(  # noqa: N802
        self, request_iterator: Iterator[replay_pb2.SampleRequest], context: grpc.ServicerContext
    ) -> Iterator[replay_pb2.SampleResponse]:
        for request in request_iterator:
            try:
                table = self.core.table(request.table)
            except Exception as error:
                self._abort(context, error)
            for _ in range(max(request.num_batches, 1)):
                start = time.perf_counter()
                try:
                    batch = table.sample(
                        request.batch_size,
                        sequence_length=max(request.sequence_length, 1),
                        timeout=self._timeout(request.timeout_s, context),
                    )
                except Exception as error:
                    self._abort(context, error)
                payload = encode_batch(batch)
                self.metrics.bytes_out.inc(len(payload))
                self.metrics.rpc_latency.labels("Sample").observe(time.perf_counter() - start)
                yield replay_pb2.SampleResponse(
                    batch=payload, table_inserts=table.stats.inserts, table_size=table.size
                )

    def UpdatePriorities(  # noqa: N802
        self, request: replay_pb2.UpdatePrioritiesRequest, context: grpc.ServicerContext
    ) -> replay_pb2.UpdatePrioritiesResponse:
        try:
            updated = self.core.table(request.table).update_priorities(
                np.asarray(request.keys, dtype=np.int64),
                np.asarray(request.priorities, dtype=np.float64),
            )
        except Exception as error:
            self._abort(context, error)
        return replay_pb2.UpdatePrioritiesResponse(updated=updated)

    def Checkpoint(  # noqa: N802
        self, request: replay_pb2.CheckpointRequest, context: grpc.ServicerContext
    ) -> replay_pb2.CheckpointResponse:
        try:
            path = self.core.checkpoint()
        except Exception as error:
            self._abort(context, error)
        if path is None:
            context.abort(
                grpc.StatusCode.FAILED_PRECONDITION,
                "this server has no checkpoint folder (start it with --checkpoint-dir)",
            )
        return replay_pb2.CheckpointResponse(path=str(path))

    def Info(  # noqa: N802
        self, request: replay_pb2.InfoRequest, context: grpc.ServicerContext
    ) -> replay_pb2.InfoResponse:
        tables = []
        for t in self.core.tables.values():
            described = t.describe()
            tables.append(
                replay_pb2.TableInfo(
                    name=t.name,
                    size=t.size,
                    max_size=t.max_size,
                    inserts=t.stats.inserts,
                    samples=t.stats.samples,
                    sampler=described["sampler"],
                    remover=described["remover"],
                    rate_limiter=described["rate_limiter"],
                    signature_json=t.signature.to_json(),
                    bytes_in_memory=t.bytes_in_memory,
                    rate_limiter_blocked_s=t.stats.insert_blocked_s + t.stats.sample_blocked_s,
                )
            )
        return replay_pb2.InfoResponse(tables=tables, uptime_s=time.monotonic() - self.core.started)


class _TokenInterceptor(grpc.ServerInterceptor):
    """Refuses every call whose `graft-token` metadata does not match (constant-time)."""

    def __init__(self, token: str) -> None:
        self._token = token.encode()

        def refuse(request: object, context: grpc.ServicerContext) -> NoReturn:
            context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or wrong graft-token metadata")

        self._refuse: grpc.RpcMethodHandler[Any, Any] = grpc.unary_unary_rpc_method_handler(refuse)

    def intercept_service(
        self,
        continuation: Callable[
            [grpc.HandlerCallDetails], Optional[grpc.RpcMethodHandler[Any, Any]]
        ],
        handler_call_details: grpc.HandlerCallDetails,
    ) -> Optional[grpc.RpcMethodHandler[Any, Any]]:
        if handler_call_details.method.startswith("/grpc.health"):
            return continuation(handler_call_details)
        sent = dict(handler_call_details.invocation_metadata or ()).get(TOKEN_METADATA_KEY, "")
        if hmac.compare_digest(str(sent).encode(), self._token):
            return continuation(handler_call_details)
        return self._refuse


@dataclass(frozen=True)
class ServerOptions:
    """How a replay server listens."""

    host: str = "127.0.0.1"
    """Bind address; anything but loopback needs `token` or `insecure`."""
    port: int = 0
    """0 picks a free port."""
    token: Optional[str] = None
    """Shared secret clients send as `graft-token` metadata."""
    insecure: bool = False
    """Allow a non-loopback bind without a token."""
    tls_cert: Optional[Path] = None
    """PEM certificate chain; with `tls_key`, the server speaks TLS."""
    tls_key: Optional[Path] = None
    """PEM private key."""
    max_message_bytes: int = DEFAULT_MAX_BYTES
    """Largest request or response; larger ones get RESOURCE_EXHAUSTED."""
    max_workers: int = 32
    """RPC threads (blocked inserts and samples each hold one)."""


@dataclass
class RunningServer:
    """A started server and the parts its owner needs to stop it gracefully."""

    server: grpc.Server
    port: int
    health: health.HealthServicer
    metrics: ReplayMetrics


def build_server(core: ReplayCore, options: ServerOptions = ServerOptions()) -> RunningServer:
    """Creates and starts the server on `options.port` (0 = any free port).

    Raises:
        InsecureBindError: a non-loopback host without a token or `insecure=True`.
    """
    o = options
    if o.host not in LOOPBACK_HOSTS and not o.token and not o.insecure:
        raise InsecureBindError(
            f"refusing to bind {o.host}: a non-loopback replay server needs a shared token "
            "(GRAFT_TOKEN or --token-file) or an explicit --insecure"
        )
    if (o.tls_cert is None) != (o.tls_key is None):
        raise ValueError("TLS needs both a certificate and a key")
    metrics = ReplayMetrics(core)
    server = grpc.server(
        futures.ThreadPoolExecutor(max_workers=o.max_workers, thread_name_prefix="replay"),
        interceptors=[_TokenInterceptor(o.token)] if o.token else [],
        options=[
            ("grpc.max_receive_message_length", o.max_message_bytes),
            ("grpc.max_send_message_length", o.max_message_bytes),
        ],
    )
    replay_pb2_grpc.add_ReplayServiceServicer_to_server(
        ReplayServicer(core, metrics, max_message_bytes=o.max_message_bytes), server
    )
    health_servicer = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    address = host_port(o.host, o.port)
    if o.tls_cert is not None and o.tls_key is not None:
        credentials = grpc.ssl_server_credentials(
            [(Path(o.tls_key).read_bytes(), Path(o.tls_cert).read_bytes())]
        )
        port = server.add_secure_port(address, credentials)
    else:
        port = server.add_insecure_port(address)
    if port == 0:
        raise OSError(f"could not bind {address}")
    server.start()
    for name in ("", SERVICE_NAME):
        health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    return RunningServer(server, port, health_servicer, metrics)


def host_port(host: str, port: int) -> str:
    """`host:port`, with an IPv6 literal in brackets (`[::1]:9100`)."""
    host = host.strip("[]")
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def _stop_when_orphaned(parent_pid: int, stop: threading.Event, poll_s: float = 1.0) -> None:
    """Sets `stop` once we are no longer `parent_pid`'s child (it died: we were re-parented).

    A launcher killed with SIGKILL cannot stop its replay server; without this the server
    would outlive it and keep its port and memory.
    """
    while not stop.wait(poll_s):
        if os.getppid() != parent_pid:
            log.warning("parent process %d is gone; stopping", parent_pid)
            stop.set()


def serve_forever(
    core: ReplayCore,
    options: ServerOptions,
    *,
    ready_file: Optional[str] = None,
    metrics_port: Optional[int] = None,
    metrics_host: str = "127.0.0.1",
    checkpoint_every_s: float = 0.0,
    grace_s: float = 5.0,
    parent_pid: Optional[int] = None,
) -> None:
    """Runs until SIGTERM/SIGINT (or, with `parent_pid`, until that parent has died), then:
    health NOT_SERVING, final checkpoint, graceful stop.

    The metrics endpoint answers without a token, so it binds `metrics_host` (loopback
    unless told otherwise), whatever `options.host` is. A failed checkpoint is logged and
    counted, and the next period tries again; the log keeps every insert meanwhile."""
    running = build_server(core, options)
    address = host_port(options.host, running.port)
    extra = ""
    if metrics_port is not None:
        bound = running.metrics.serve(metrics_port, metrics_host.strip("[]"))
        extra = f", metrics on http://{host_port(metrics_host, bound)}/metrics"
    print(f"replay server listening on {address}{extra}", flush=True)
    log.info("tables: %s", sorted(core.tables))
    if ready_file:
        with open(ready_file + ".tmp", "w") as f:
            json.dump({"address": address}, f)
        os.replace(ready_file + ".tmp", ready_file)  # atomic: readers never see half a file
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    if parent_pid is not None:
        threading.Thread(target=_stop_when_orphaned, args=(parent_pid, stop), daemon=True).start()
    while not stop.wait(checkpoint_every_s or None):
        with suppress(StorageError):  # logged and counted by the core
            core.checkpoint()  # periodic; sampling goes on while the file is written
    running.health.enter_graceful_shutdown()
    with suppress(StorageError):
        core.checkpoint()
    running.server.stop(grace_s).wait()
    core.close()
