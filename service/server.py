"""The replay gRPC server: a thin servicer over ReplayCore, plus its process entry point."""

from __future__ import annotations

import hmac
import json
import logging
import os
import signal
import threading
import time
from concurrent import futures
from typing import Optional

import grpc
from grpc_health.v1 import health, health_pb2, health_pb2_grpc

from service._proto import replay_pb2, replay_pb2_grpc
from service.codec import DEFAULT_MAX_BYTES, CodecError, decode_batch, encode_batch
from service.replay import ReplayCore, UnknownTable
from service.signature import SignatureError
from service.table import RateLimitTimeout

log = logging.getLogger(__name__)

SERVICE_NAME = "graft.replay.v1.ReplayService"
TOKEN_METADATA_KEY = "graft-token"
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})


class InsecureBindError(ValueError):
    """Binding a non-loopback address without a token or an explicit opt-out."""


def _abort_for(context: grpc.ServicerContext, error: Exception) -> None:
    """Maps core exceptions to the gRPC status a client can act on."""
    if isinstance(error, (CodecError, SignatureError, ValueError)):
        context.abort(grpc.StatusCode.INVALID_ARGUMENT, str(error))
    if isinstance(error, UnknownTable):
        context.abort(grpc.StatusCode.NOT_FOUND, str(error))
    if isinstance(error, RateLimitTimeout):
        context.abort(grpc.StatusCode.DEADLINE_EXCEEDED, str(error))
    raise error


def _timeout(request_timeout: float, context: grpc.ServicerContext) -> Optional[float]:
    """The tighter of the request's own timeout and the RPC deadline."""
    remaining = context.time_remaining()
    limits = [t for t in (request_timeout or None, remaining) if t is not None]
    return min(limits) if limits else None


class ReplayServicer(replay_pb2_grpc.ReplayServiceServicer):
    """Decode, validate, call the core, encode. Nothing else lives here."""

    def __init__(self, core: ReplayCore, *, max_message_bytes: int = DEFAULT_MAX_BYTES) -> None:
        self.core = core
        self.max_message_bytes = max_message_bytes

    def Insert(self, request_iterator, context):  # noqa: N802 (gRPC method name)
        stored = dropped = 0
        acked: dict[str, int] = {}
        for request in request_iterator:
            try:
                batch = decode_batch(request.batch, max_bytes=self.max_message_bytes)
                result = self.core.insert(
                    request.table,
                    batch,
                    writer_id=request.writer_id,
                    sequence=request.sequence,
                    timeout=_timeout(request.timeout_s, context),
                )
            except Exception as error:  # mapped to a status, or re-raised
                _abort_for(context, error)
            if result is None:
                dropped += 1
            else:
                stored += result
            if request.writer_id:
                acked[request.writer_id] = self.core.acked.get(request.writer_id, 0)
        return replay_pb2.InsertResponse(
            items_inserted=stored, batches_dropped_as_duplicates=dropped, acked_sequence=acked
        )

    def Sample(self, request_iterator, context):  # noqa: N802
        for request in request_iterator:
            try:
                table = self.core.table(request.table)
                if request.batch_size < 1:
                    raise ValueError(f"batch_size must be >= 1, got {request.batch_size}")
                if request.sequence_length > 1:
                    raise ValueError("sequence_length > 1 is not supported by this table")
            except Exception as error:
                _abort_for(context, error)
            for _ in range(max(request.num_batches, 1)):
                try:
                    batch = table.sample(
                        request.batch_size, timeout=_timeout(request.timeout_s, context)
                    )
                except Exception as error:
                    _abort_for(context, error)
                yield replay_pb2.SampleResponse(
                    batch=encode_batch(batch),
                    table_inserts=table.stats.inserts,
                    table_size=table.size,
                )

    def Info(self, request, context):  # noqa: N802
        tables = [
            replay_pb2.TableInfo(
                name=t.name,
                size=t.size,
                max_size=t.max_size,
                inserts=t.stats.inserts,
                samples=t.stats.samples,
                sampler="uniform",
                remover="fifo",
                rate_limiter=t.rate_limiter.describe(),
                signature_json=t.signature.to_json(),
                bytes_in_memory=t.bytes_in_memory,
                rate_limiter_blocked_s=t.stats.insert_blocked_s + t.stats.sample_blocked_s,
            )
            for t in self.core.tables.values()
        ]
        return replay_pb2.InfoResponse(tables=tables, uptime_s=time.monotonic() - self.core.started)


class _TokenInterceptor(grpc.ServerInterceptor):
    """Refuses every call whose `graft-token` metadata does not match (constant-time)."""

    def __init__(self, token: str) -> None:
        self._token = token.encode()

        def refuse(request, context):
            context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or wrong graft-token metadata")

        self._refuse = grpc.unary_unary_rpc_method_handler(refuse)

    def intercept_service(self, continuation, handler_call_details):
        if handler_call_details.method.startswith("/grpc.health"):
            return continuation(handler_call_details)
        sent = dict(handler_call_details.invocation_metadata or ()).get(TOKEN_METADATA_KEY, "")
        if hmac.compare_digest(str(sent).encode(), self._token):
            return continuation(handler_call_details)
        return self._refuse


def build_server(
    core: ReplayCore,
    *,
    host: str = "127.0.0.1",
    port: int = 0,
    token: Optional[str] = None,
    insecure: bool = False,
    max_message_bytes: int = DEFAULT_MAX_BYTES,
    max_workers: int = 32,
) -> tuple[grpc.Server, int, health.HealthServicer]:
    """Creates (but does not start) the server; returns (server, bound port, health).

    Raises:
        InsecureBindError: `host` is not loopback and neither a token nor
            `insecure=True` was given.
    """
    if host not in LOOPBACK_HOSTS and not token and not insecure:
        raise InsecureBindError(
            f"refusing to bind {host}: a non-loopback replay server needs a shared token "
            "(--token or GRAFT_TOKEN) or an explicit --insecure"
        )
    interceptors = [_TokenInterceptor(token)] if token else []
    server = grpc.server(
        futures.ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="replay"),
        interceptors=interceptors,
        options=[
            ("grpc.max_receive_message_length", max_message_bytes),
            ("grpc.max_send_message_length", max_message_bytes),
        ],
        maximum_concurrent_rpcs=max_workers - 2,
    )
    replay_pb2_grpc.add_ReplayServiceServicer_to_server(
        ReplayServicer(core, max_message_bytes=max_message_bytes), server
    )
    health_servicer = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    bound = server.add_insecure_port(f"{host}:{port}")
    if bound == 0:
        raise OSError(f"could not bind {host}:{port}")
    for name in ("", SERVICE_NAME):
        health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    return server, bound, health_servicer


def serve_forever(
    core: ReplayCore,
    *,
    host: str,
    port: int,
    token: Optional[str],
    insecure: bool,
    ready_file: Optional[str] = None,
    grace_s: float = 5.0,
) -> None:
    """Runs until SIGTERM/SIGINT: then health NOT_SERVING and a graceful stop."""
    server, bound, health_servicer = build_server(
        core, host=host, port=port, token=token, insecure=insecure
    )
    server.start()
    address = f"{host}:{bound}"
    log.info("replay server listening on %s with tables %s", address, sorted(core.tables))
    print(f"replay server listening on {address}", flush=True)
    if ready_file:
        with open(ready_file + ".tmp", "w") as f:
            json.dump({"address": address}, f)
        os.replace(ready_file + ".tmp", ready_file)  # atomic: readers never see half a file
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    stop.wait()
    health_servicer.enter_graceful_shutdown()
    server.stop(grace_s).wait()
