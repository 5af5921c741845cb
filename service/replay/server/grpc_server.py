"""Builds and starts the replay gRPC server: `build_server` returns it with its port
(0 binds a free one), on an asyncio event loop thread of its own.

The server runs on grpc.aio: a call that waits (on a rate limiter, on its client's next
credit, on a slow reader) is a parked coroutine, so idle streams cost no thread and
health checks and Info always answer. A port in use is refused, never shared.
"""

from __future__ import annotations

import asyncio
import errno
import socket
import threading
from collections.abc import Coroutine
from concurrent import futures
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, TypeVar

import grpc
from grpc_health.v1 import _async as aio_health
from grpc_health.v1 import health_pb2, health_pb2_grpc

from service.replay._proto import replay_pb2_grpc
from service.replay.codec import DEFAULT_MAX_BYTES
from service.replay.server.allocator import FreedMemory
from service.replay.server.rpc_meter import NoMeter, RpcMeter
from service.replay.server.servicer import ReplayServicer
from service.replay.server.store import ReplayCore
from service.replay.server.thread_pool import HotThreadPool
from service.replay.server.token_auth import TokenInterceptor

if TYPE_CHECKING:
    from service.replay.server.prom import ReplayMetrics

SERVICE_NAME = "graft.replay.v1.ReplayService"
LOOPBACK_HOSTS = frozenset({"127.0.0.1", "localhost", "::1", "[::1]"})

T = TypeVar("T")


class InsecureBindError(ValueError):
    """Binding a non-loopback address without a token or an explicit opt-out."""


class PortUnavailable(ValueError):
    """The port is in use (ports are never shared) or the address cannot be bound."""


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
    metrics: Optional[ReplayMetrics]
    """Its Prometheus figures, where `build_server` was asked for them."""
    freed_memory: FreedMemory
    """Hands back what refused and aborted calls freed, once its `run` is started."""


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
    meter: RpcMeter,
    o: ServerOptions,
    loop: asyncio.AbstractEventLoop,
    pool: futures.Executor,
    freed: FreedMemory,
) -> tuple[grpc.aio.Server, ReplayServicer, aio_health.HealthServicer, int]:
    server = grpc.aio.server(
        interceptors=[TokenInterceptor(o.token)] if o.token else [],
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
        core,
        meter,
        loop=loop,
        pool=pool,
        max_message_bytes=o.max_message_bytes,
        ended_badly=freed.call_ended_badly,
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


def build_server(
    core: ReplayCore, options: ServerOptions = ServerOptions(), *, metrics: bool = False
) -> RunningServer:
    """Creates and starts the server on `options.port` (0 = any free port) on an event
    loop thread of its own; with `metrics`, it keeps Prometheus figures (served by
    `RunningServer.metrics.serve`).

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
    freed = FreedMemory()
    prometheus: Optional[ReplayMetrics] = None
    meter: RpcMeter = NoMeter()
    if metrics:
        from service.replay.server.prom import ReplayMetrics

        prometheus = meter = ReplayMetrics(core, freed)
    loop = _EventLoopThread()
    pool = HotThreadPool(o.max_workers, thread_name_prefix="replay")
    try:
        server, servicer, health_servicer, port = loop.run(
            _start(core, meter, o, loop.loop, pool, freed)
        )
    except BaseException:
        pool.shutdown()
        loop.close()
        raise
    return RunningServer(
        ServerHandle(server, servicer, loop, pool),
        port,
        HealthHandle(health_servicer, loop),
        prometheus,
        freed,
    )


def host_port(host: str, port: int) -> str:
    """`host:port`, with an IPv6 literal in brackets (`[::1]:9100`)."""
    host = host.strip("[]")
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
