"""The replay gRPC server: a thin asynchronous servicer over ReplayCore, plus its process
entry point.

The server runs on grpc.aio: a call that waits (on a rate limiter, on its client's next
credit, on a slow reader) is a parked coroutine, so idle streams cost no thread and
health checks and Info always answer. Table work runs briefly: inline when small and its
locks are free, else on a bounded thread pool.
"""

from __future__ import annotations

import asyncio
import errno
import functools
import hmac
import json
import logging
import math
import os
import signal
import socket
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Coroutine
from concurrent import futures
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, Optional, TypeVar

import grpc
import numpy as np
from grpc_health.v1 import _async as aio_health
from grpc_health.v1 import health_pb2, health_pb2_grpc

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
from service.replay.server.store import CallEnded, ReplayCore, StagedInsert, UnknownTable
from service.replay.server.table import LockBusy, RateLimitTimeout, Table
from service.replay.server.thread_pool import HotThreadPool
from service.replay.server.waiting import CallState, Wakeups, wait_for_change
from service.replay.server.writers import MAX_WRITER_ID_BYTES, Claim

log = logging.getLogger(__name__)

SERVICE_NAME = "graft.replay.v1.ReplayService"
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})
MAX_TABLE_NAME_BYTES = 256
MAX_STREAM_BATCHES = 1024
"""Most batches one Insert stream may carry (it is held whole until it ends)."""
MAX_SAMPLE_CREDITS = 1 << 16
"""Most batches one SampleRequest may ask for (`num_batches`)."""
RESPONSE_OVERHEAD_BYTES = 64 * 1024
"""Room kept in a sample response for column headers and the message's other fields."""
INLINE_BYTES = 256 * 1024
"""Table work on at most this many bytes runs on the event loop if its locks are free:
a hop to the pool and back costs more than the work. Larger work, work that meets a
held lock, and inserts that fsync run on the pool."""

T = TypeVar("T")


class InsecureBindError(ValueError):
    """Binding a non-loopback address without a token or an explicit opt-out."""


class PortUnavailable(ValueError):
    """The port is in use (ports are never shared) or the address cannot be bound."""


_STATUS_OF = (
    (PayloadTooLarge, grpc.StatusCode.RESOURCE_EXHAUSTED),
    (UnknownTable, grpc.StatusCode.NOT_FOUND),
    ((RateLimitTimeout, CallEnded), grpc.StatusCode.DEADLINE_EXCEEDED),
    (StorageError, grpc.StatusCode.UNAVAILABLE),  # e.g. a full disk; a resend may succeed
    ((CodecError, SignatureError, ValueError), grpc.StatusCode.INVALID_ARGUMENT),
)


def _check_table_name(name: str) -> None:
    if len(name.encode()) > MAX_TABLE_NAME_BYTES:
        raise ValueError(f"table name is longer than the {MAX_TABLE_NAME_BYTES}-byte limit")


def _earlier(a: Optional[float], b: Optional[float]) -> Optional[float]:
    return b if a is None else a if b is None else min(a, b)


def _check_timeout(timeout_s: float) -> None:
    if not (math.isfinite(timeout_s) and timeout_s >= 0):
        raise ValueError(f"timeout_s must be a finite number >= 0, got {timeout_s}")


class ReplayServicer(replay_pb2_grpc.ReplayServiceServicer):
    """Decode, validate, call the core, encode. Nothing else lives here.

    Every count a request carries is checked against the table and the message limit
    before anything is allocated. An Insert stream is stored whole when it ends, or
    not at all; a batch waiting on the rate limiter holds its (writer, sequence) claim.
    """

    def __init__(
        self,
        core: ReplayCore,
        metrics: ReplayMetrics,
        *,
        loop: asyncio.AbstractEventLoop,
        pool: futures.Executor,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
    ) -> None:
        self.core = core
        self.metrics = metrics
        self.max_message_bytes = max_message_bytes
        self._loop = loop
        self._pool = pool
        self._wakeups = Wakeups(loop)
        self._watching = [(t, self._wakeups.notifier(t.name)) for t in core.tables.values()]
        for table, notify in self._watching:
            table.watch(notify)

    def close(self) -> None:
        """Stops listening to the tables (the core may outlive this server)."""
        for table, notify in self._watching:
            table.unwatch(notify)

    async def _abort(
        self, context: grpc.aio.ServicerContext[Any, Any], error: Exception
    ) -> NoReturn:
        """Maps a core exception to the status a client can act on; re-raises the unknown."""
        for kinds, code in _STATUS_OF:
            if isinstance(error, kinds):
                self.metrics.errors.labels(code.name).inc()
                await context.abort(code, str(error))
        raise error

    async def _run(self, function: Callable[..., T], *args: Any) -> T:
        """Runs table work on the pool: briefly, never waiting on a limiter."""
        return await self._loop.run_in_executor(self._pool, functools.partial(function, *args))

    async def _attempt(self, inline: bool, function: Callable[..., T], *args: Any) -> T:
        """Runs `function(*args, blocking=...)` on the loop if `inline` and its locks are
        free, else on the pool."""
        if inline:
            try:
                return function(*args, blocking=False)
            except LockBusy:
                pass
        return await self._run(function, *args)

    async def _until(
        self,
        keys: tuple[str, ...],
        attempt: Callable[..., Optional[T]],
        deadline: Optional[float],
        *,
        inline: bool,
        table: Table,
        what: str,
    ) -> T:
        """Retries `attempt(seconds waited so far, blocking=...)` after each change of
        `keys` until it returns something (see `_attempt` for `inline`); past `deadline`,
        raises `table`'s error for a `what` ("insert", "sample") not admitted."""
        start = time.monotonic()
        result = await self._attempt(inline, attempt, 0.0)
        if result is not None:
            return result  # the common case: no need to listen for changes
        with self._wakeups.waiting(*keys) as changed:
            while True:
                changed.clear()
                result = await self._attempt(inline, attempt, time.monotonic() - start)
                if result is not None:
                    return result
                if not await wait_for_change(changed, deadline):
                    raise table.not_admitted(what, time.monotonic() - start)

    # ----------------------------------------------------------------- Insert

    def _check_insert(
        self, request: replay_pb2.InsertRequest, stream_batches: int, stream_bytes: int
    ) -> Table:
        _check_table_name(request.table)
        writer_bytes = len(request.writer_id.encode())
        if writer_bytes > MAX_WRITER_ID_BYTES:
            raise ValueError(
                f"writer_id of {writer_bytes} bytes is longer than the "
                f"{MAX_WRITER_ID_BYTES}-byte limit"
            )
        _check_timeout(request.timeout_s)
        if stream_batches > MAX_STREAM_BATCHES or stream_bytes > self.max_message_bytes:
            raise PayloadTooLarge(
                f"an Insert stream carries at most {MAX_STREAM_BATCHES} batches and "
                f"{self.max_message_bytes} bytes (it is stored whole when it ends), this one "
                f"{stream_batches} and {stream_bytes} so far; split it into several calls"
            )
        return self.core.table(request.table)

    async def _claim(
        self, writer: str, sequence: int, call: CallState, deadline: Optional[float]
    ) -> bool:
        """Claims (writer, sequence) for this call, waiting while another call holds it;
        False if the batch is already stored (a resend)."""
        with self._wakeups.waiting(Wakeups.CLAIMS) as released:
            while True:
                released.clear()
                found = self.core.writers.claim(writer, sequence, call)
                if found is not Claim.BUSY:
                    return found is Claim.CLAIMED
                if not await wait_for_change(released, deadline):
                    raise CallEnded(
                        f"batch {sequence} of writer '{writer}' was still being stored by "
                        "another call at this call's deadline; this call stored nothing"
                    )

    def _commit(
        self,
        received: list[tuple[Table, replay_pb2.InsertRequest]],
        staged: list[StagedInsert],
        call: CallState,
        deadline: Optional[float],
        waited: float,
        *,
        blocking: bool = True,
    ) -> Optional[tuple[int, int]]:
        """One attempt to store the whole stream (None: the limiter says wait). The first
        attempt decodes and validates the batches into `staged`."""
        if not staged:
            staged.extend(
                StagedInsert(
                    table.name,
                    table.prepare(decode_batch(r.batch, max_bytes=self.max_message_bytes)),
                    r.writer_id,
                    r.sequence,
                    r.batch,
                )
                for table, r in received
            )
        return self.core.commit(
            staged, alive=lambda: call.alive(deadline), blocked_s=waited, blocking=blocking
        )

    async def Insert(  # noqa: N802 (gRPC method name)
        self,
        request_iterator: AsyncIterator[replay_pb2.InsertRequest],
        context: grpc.aio.ServicerContext[Any, Any],
    ) -> replay_pb2.InsertResponse:
        start = time.perf_counter()
        call = CallState(context)
        received: list[tuple[Table, replay_pb2.InsertRequest]] = []
        staged: list[StagedInsert] = []
        claimed: list[tuple[str, int]] = []
        writers: dict[str, None] = {}  # in order of first appearance
        deadline, stream_batches, stream_bytes, stored, dropped = call.deadline, 0, 0, 0, 0
        try:
            async for request in request_iterator:
                self.metrics.bytes_in.inc(len(request.batch))
                stream_batches += 1
                stream_bytes += len(request.batch)
                table = self._check_insert(request, stream_batches, stream_bytes)
                deadline = _earlier(deadline, call.deadline_with(request.timeout_s))
                writer, sequence = request.writer_id, request.sequence
                if writer:
                    writers[writer] = None
                    if not await self._claim(writer, sequence, call, deadline):
                        dropped += 1
                        continue
                    claimed.append((writer, sequence))
                received.append((table, request))
            if received:
                stored, resent = await self._until(
                    tuple(sorted({table.name for table, _ in received})),
                    functools.partial(self._commit, received, staged, call, deadline),
                    deadline,
                    inline=stream_bytes <= INLINE_BYTES and not self.core.fsync,
                    table=received[0][0],
                    what="insert",
                )
                dropped += resent
        except asyncio.CancelledError:
            call.end()
            raise
        except Exception as error:
            await self._abort(context, error)
        finally:
            self.core.writers.release(call, claimed)
            self._wakeups.wake(Wakeups.CLAIMS)
        self.metrics.rpc_latency.labels("Insert").observe(time.perf_counter() - start)
        return replay_pb2.InsertResponse(
            items_inserted=stored,
            batches_dropped_as_duplicates=dropped,
            acked_sequence={w: self.core.writers.acked(w) for w in writers},
        )

    # ----------------------------------------------------------------- Sample

    def _check_sample(self, request: replay_pb2.SampleRequest) -> Table:
        _check_table_name(request.table)
        table = self.core.table(request.table)
        _check_timeout(request.timeout_s)
        if request.num_batches > MAX_SAMPLE_CREDITS:
            raise ValueError(
                f"num_batches {request.num_batches} exceeds the limit of "
                f"{MAX_SAMPLE_CREDITS} batches per request"
            )
        k = max(request.sequence_length, 1)
        table.check_sample(request.batch_size, k)
        room = self.max_message_bytes - RESPONSE_OVERHEAD_BYTES
        need = table.sampled_bytes(request.batch_size, k)
        if need > room:
            raise PayloadTooLarge(
                f"batch_size {request.batch_size} x sequence_length {k} needs "
                f"{need / 2**20:.0f} MiB per response, over the "
                f"{self.max_message_bytes / 2**20:g} MiB message limit; ask for at most "
                f"{room // table.sampled_bytes(1, k)}"
            )
        return table

    @staticmethod
    def _sample_once(
        table: Table,
        request: replay_pb2.SampleRequest,
        call: CallState,
        waited: float,
        *,
        blocking: bool = True,
    ) -> Optional[bytes]:
        """One attempt: an encoded batch, or None while the limiter says wait."""
        if not call.alive():
            raise CallEnded("the call was cancelled or passed its deadline")
        batch = table.try_sample(
            request.batch_size,
            sequence_length=max(request.sequence_length, 1),
            blocked_s=waited,
            blocking=blocking,
        )
        return None if batch is None else encode_batch(batch)

    async def Sample(  # noqa: N802
        self,
        request_iterator: AsyncIterator[replay_pb2.SampleRequest],
        context: grpc.aio.ServicerContext[Any, Any],
    ) -> AsyncIterator[replay_pb2.SampleResponse]:
        call = CallState(context)
        try:
            async for request in request_iterator:  # each request grants num_batches credits
                table = self._check_sample(request)
                k = max(request.sequence_length, 1)
                inline = table.sampled_bytes(request.batch_size, k) <= INLINE_BYTES
                for _ in range(max(request.num_batches, 1)):
                    start = time.perf_counter()
                    deadline = call.deadline_with(request.timeout_s)
                    payload = await self._until(
                        (table.name,),
                        functools.partial(self._sample_once, table, request, call),
                        deadline,
                        inline=inline,
                        table=table,
                        what="sample",
                    )
                    self.metrics.bytes_out.inc(len(payload))
                    self.metrics.rpc_latency.labels("Sample").observe(time.perf_counter() - start)
                    yield replay_pb2.SampleResponse(
                        batch=payload, table_inserts=table.stats.inserts, table_size=table.size
                    )
        except asyncio.CancelledError:
            call.end()
            raise
        except Exception as error:
            await self._abort(context, error)

    # ------------------------------------------------------------------ other

    async def UpdatePriorities(  # noqa: N802
        self,
        request: replay_pb2.UpdatePrioritiesRequest,
        context: grpc.aio.ServicerContext[Any, Any],
    ) -> replay_pb2.UpdatePrioritiesResponse:
        try:
            _check_table_name(request.table)
            table = self.core.table(request.table)
            updated = await self._run(
                table.update_priorities,
                np.asarray(request.keys, dtype=np.uint64).astype(np.int64),
                np.asarray(request.priorities, dtype=np.float64),
            )
        except Exception as error:
            await self._abort(context, error)
        return replay_pb2.UpdatePrioritiesResponse(updated=updated)

    async def Checkpoint(  # noqa: N802
        self, request: replay_pb2.CheckpointRequest, context: grpc.aio.ServicerContext[Any, Any]
    ) -> replay_pb2.CheckpointResponse:
        try:
            path = await self._run(self.core.checkpoint)
        except Exception as error:
            await self._abort(context, error)
        if path is None:
            await context.abort(
                grpc.StatusCode.FAILED_PRECONDITION,
                "this server has no checkpoint folder (start it with --checkpoint-dir)",
            )
        return replay_pb2.CheckpointResponse(path=str(path))

    async def Info(  # noqa: N802
        self, request: replay_pb2.InfoRequest, context: grpc.aio.ServicerContext[Any, Any]
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


_HANDLER_KINDS = {
    (False, False): grpc.unary_unary_rpc_method_handler,
    (True, False): grpc.stream_unary_rpc_method_handler,
    (False, True): grpc.unary_stream_rpc_method_handler,
    (True, True): grpc.stream_stream_rpc_method_handler,
}


async def _refuse(request: object, context: grpc.aio.ServicerContext[Any, Any]) -> NoReturn:
    await context.abort(grpc.StatusCode.UNAUTHENTICATED, "missing or wrong graft-token metadata")


class _TokenInterceptor(grpc.aio.ServerInterceptor):
    """Refuses every call whose `graft-token` metadata does not match (constant-time)."""

    def __init__(self, token: str) -> None:
        self._token = token.encode()

    async def intercept_service(
        self,
        continuation: Callable[
            [grpc.HandlerCallDetails], Awaitable[Optional[grpc.RpcMethodHandler[Any, Any]]]
        ],
        handler_call_details: grpc.HandlerCallDetails,
    ) -> Optional[grpc.RpcMethodHandler[Any, Any]]:
        handler = await continuation(handler_call_details)
        if handler is None or handler_call_details.method.startswith("/grpc.health"):
            return handler
        sent = dict(handler_call_details.invocation_metadata or ()).get(TOKEN_METADATA_KEY, "")
        if hmac.compare_digest(str(sent).encode(), self._token):
            return handler
        make = _HANDLER_KINDS[(handler.request_streaming, handler.response_streaming)]
        refusal: grpc.RpcMethodHandler[Any, Any] = make(
            _refuse, request_deserializer=handler.request_deserializer
        )
        return refusal


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
    """Threads for table work (decoding, storing, sampling); a waiting call holds none."""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise ValueError(f"port {self.port} is outside 0..65535")
        if self.max_workers < 1:
            raise ValueError(f"max_workers must be >= 1, got {self.max_workers}")


class _EventLoopThread:
    """An asyncio event loop on a daemon thread, driven from synchronous code."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self.loop.run_forever, name="replay-aio", daemon=True
        )
        self._thread.start()

    def run(self, coroutine: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result()

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join()
        self.loop.close()


class ServerHandle:
    """The asynchronous server, stopped from synchronous code as a `grpc.Server` is."""

    def __init__(
        self,
        server: grpc.aio.Server,
        servicer: ReplayServicer,
        loop: _EventLoopThread,
        pool: futures.Executor,
    ) -> None:
        self._server, self._servicer, self._loop, self._pool = server, servicer, loop, pool
        self._stopped = threading.Event()

    def stop(self, grace: Optional[float]) -> threading.Event:
        """Refuses new calls, gives running ones `grace` seconds, then finishes the table
        work already started; returns an event that is set (it already is)."""
        if not self._stopped.is_set():
            self._loop.run(self._server.stop(grace))
            self._pool.shutdown(wait=True)
            self._servicer.close()
            self._loop.close()
            self._stopped.set()
        return self._stopped


class HealthHandle:
    """The health service, driven from synchronous code."""

    def __init__(self, servicer: aio_health.HealthServicer, loop: _EventLoopThread) -> None:
        self._servicer, self._loop = servicer, loop

    def enter_graceful_shutdown(self) -> None:
        """Every service NOT_SERVING from now on."""
        self._loop.run(self._servicer.enter_graceful_shutdown())


@dataclass
class RunningServer:
    """A started server and the parts its owner needs to stop it gracefully."""

    server: ServerHandle
    port: int
    health: HealthHandle
    metrics: ReplayMetrics


def _cannot_bind(host: str, port: int) -> Optional[PortUnavailable]:
    """Why host:port cannot be listened on, found by binding a plain socket (gRPC's own
    bind failure says nothing a user can act on, and logs it); None if it can."""
    bare = host.strip("[]")
    family = socket.AF_INET6 if ":" in bare else socket.AF_INET
    try:
        with socket.socket(family) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as gRPC does
            probe.bind((bare, port))
    except OSError as error:
        if error.errno == errno.EADDRINUSE:
            return PortUnavailable(
                f"port {port} is in use on {host} (another replay server?); "
                "a replay server never shares its port"
            )
        return PortUnavailable(f"cannot listen on {host}:{port}: {error.strerror}")
    return None


async def _start(
    core: ReplayCore,
    metrics: ReplayMetrics,
    o: ServerOptions,
    loop: asyncio.AbstractEventLoop,
    pool: futures.Executor,
) -> tuple[grpc.aio.Server, ReplayServicer, aio_health.HealthServicer, int]:
    server = grpc.aio.server(
        interceptors=[_TokenInterceptor(o.token)] if o.token else [],
        options=[
            ("grpc.max_receive_message_length", o.max_message_bytes),
            ("grpc.max_send_message_length", o.max_message_bytes),
            ("grpc.so_reuseport", 0),  # gRPC shares ports by default: two servers, one port
            # Ping idle connections: a peer gone without a word (half-open TCP) is found
            # within ~40 s and its calls cancelled, so their claims do not hold up resends.
            ("grpc.keepalive_time_ms", 30_000),
            ("grpc.keepalive_timeout_ms", 10_000),
        ],
    )
    servicer = ReplayServicer(
        core, metrics, loop=loop, pool=pool, max_message_bytes=o.max_message_bytes
    )
    replay_pb2_grpc.add_ReplayServiceServicer_to_server(servicer, server)
    health_servicer = aio_health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    address = host_port(o.host, o.port)
    if o.port and (refused := _cannot_bind(o.host, o.port)) is not None:
        servicer.close()
        raise refused
    try:
        if o.tls_cert is not None and o.tls_key is not None:
            credentials = grpc.ssl_server_credentials(
                [(Path(o.tls_key).read_bytes(), Path(o.tls_cert).read_bytes())]
            )
            port = server.add_secure_port(address, credentials)
        else:
            port = server.add_insecure_port(address)
    except RuntimeError:  # taken since the probe, or a host gRPC cannot resolve
        servicer.close()
        raise _cannot_bind(o.host, o.port) or PortUnavailable(
            f"cannot listen on {address}"
        ) from None
    await server.start()
    for name in ("", SERVICE_NAME):
        await health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
    return server, servicer, health_servicer, port


def build_server(core: ReplayCore, options: ServerOptions = ServerOptions()) -> RunningServer:
    """Creates and starts the server on `options.port` (0 = any free port) on an event
    loop thread of its own.

    Raises:
        InsecureBindError: a non-loopback host without a token or `insecure=True`.
        PortUnavailable: the port is in use (never shared) or the host cannot be bound.
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
    loop = _EventLoopThread()
    pool = HotThreadPool(o.max_workers, thread_name_prefix="replay")
    try:
        server, servicer, health_servicer, port = loop.run(
            _start(core, metrics, o, loop.loop, pool)
        )
    except BaseException:
        pool.shutdown()
        loop.close()
        raise
    return RunningServer(
        ServerHandle(server, servicer, loop, pool),
        port,
        HealthHandle(health_servicer, loop),
        metrics,
    )


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
