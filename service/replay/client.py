"""Python client for the replay server.

The client pickles as its address (and token), so it can be handed to Ray actors
without dragging a live channel along; each process opens its own channel lazily.
"""

from __future__ import annotations

import json
import queue
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Optional, Protocol, Union

import grpc
import numpy as np

from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.codec import (
    DEFAULT_MAX_BYTES,
    TOKEN_METADATA_KEY,
    Batch,
    CodecError,
    decode_batch,
    encode_batch,
    split_batch,
)
from service.replay.errors import (
    DeadlineExceeded,
    ReplayError,
    Unavailable,
    typed,
)


@dataclass(frozen=True)
class TableStatus:
    """What `info()` reports about one table."""

    name: str
    size: int
    max_size: int
    inserts: int
    samples: int
    sampler: str
    remover: str
    rate_limiter: str
    signature: dict[str, Any]
    bytes_in_memory: int
    """What the table may fill at max_size."""
    rate_limiter_blocked_s: float
    bytes_used: int = 0
    """What its stored items fill now."""
    memory_budget_bytes: int = 0
    """What the server's tables may fill together (0: the server checked no budget)."""
    memory_budget: str = ""
    """Where that budget comes from (the cgroup limit, the machine's memory, --max-memory)."""


class ReplayClient:
    """Inserts into and samples from one replay server.

    Args:
        address: "host:port" of the server.
        token: shared secret for servers bound beyond loopback.
        max_retries: how often an UNAVAILABLE insert is retried (with backoff) before
            giving up; resends carry the same sequence number, so nothing is doubled.
    """

    def __init__(
        self,
        address: str,
        *,
        token: Optional[str] = None,
        max_retries: int = 8,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
        tls_root_cert: Optional[str] = None,
        writer_id: Optional[str] = None,
    ) -> None:
        self.address = address
        self.token = token
        self.tls_root_cert = tls_root_cert
        self.max_retries = max_retries
        self.max_message_bytes = max_message_bytes
        self.writer_id = writer_id or uuid.uuid4().hex
        self._sequence = 0
        self._channel: Optional[grpc.Channel] = None
        self._stub: Optional[replay_pb2_grpc.ReplayServiceStub] = None

    def __reduce__(self) -> tuple[Callable[..., ReplayClient], tuple[Any, ...]]:
        return (
            _rebuild_client,
            # Not the writer id: every unpickled copy is a writer of its own.
            (
                self.address,
                self.token,
                self.max_retries,
                self.max_message_bytes,
                self.tls_root_cert,
            ),
        )

    @property
    def stub(self) -> replay_pb2_grpc.ReplayServiceStub:
        if self._stub is None:
            options = [
                ("grpc.max_receive_message_length", self.max_message_bytes),
                ("grpc.max_send_message_length", self.max_message_bytes),
            ]
            if self.tls_root_cert:
                with open(self.tls_root_cert, "rb") as f:
                    credentials = grpc.ssl_channel_credentials(root_certificates=f.read())
                self._channel = grpc.secure_channel(self.address, credentials, options=options)
            else:
                self._channel = grpc.insecure_channel(self.address, options=options)
            self._stub = replay_pb2_grpc.ReplayServiceStub(self._channel)
        return self._stub

    @property
    def _metadata(self) -> tuple[tuple[str, str], ...]:
        return ((TOKEN_METADATA_KEY, self.token),) if self.token else ()

    def close(self) -> None:
        if self._channel is not None:
            self._channel.close()
        self._channel = self._stub = None

    def insert(
        self, table: str, columns: Mapping[str, np.ndarray], *, timeout: Optional[float] = None
    ) -> int:
        """Stores one batch of columns; blocks while the table's rate limiter says wait.

        Returns:
            Items stored (0 if the server already held this batch from a lost ack).
        """
        self._sequence += 1
        request = replay_pb2.InsertRequest(
            table=table,
            batch=encode_batch(columns),
            writer_id=self.writer_id,
            sequence=self._sequence,
            timeout_s=timeout or 0.0,
        )
        for attempt in range(self.max_retries + 1):
            try:
                response: replay_pb2.InsertResponse = self.stub.Insert(
                    iter((request,)), metadata=self._metadata
                )
                return response.items_inserted
            except grpc.RpcError as error:
                if error.code() != grpc.StatusCode.UNAVAILABLE or attempt == self.max_retries:
                    raise typed(error) from None
                time.sleep(min(0.05 * 2**attempt, 2.0))
        raise AssertionError("unreachable")

    def sample(
        self,
        table: str,
        batch_size: int,
        *,
        sequence_length: int = 1,
        timeout: Optional[float] = None,
    ) -> Batch:
        """Draws one batch (blocks until the rate limiter admits it or `timeout`).

        With `sequence_length` k > 1 each item is a window of k consecutive steps of one
        episode: data columns come shaped [B, k, ...] and `_key` [B, k].
        """
        response = self._sample_once(table, batch_size, sequence_length, timeout)
        return decode_batch(response.batch, max_bytes=self.max_message_bytes)

    def _sample_once(
        self, table: str, batch_size: int, sequence_length: int, timeout: Optional[float]
    ) -> replay_pb2.SampleResponse:
        request = replay_pb2.SampleRequest(
            table=table,
            batch_size=batch_size,
            num_batches=1,
            sequence_length=sequence_length,
            timeout_s=timeout or 0.0,
        )
        try:
            for response in self.stub.Sample(iter((request,)), metadata=self._metadata):
                sampled: replay_pb2.SampleResponse = response
                return sampled
        except grpc.RpcError as error:
            raise typed(error) from None
        raise ReplayError("server closed the sample stream without a batch")

    def sample_stream(
        self,
        table: str,
        batch_size: int,
        *,
        prefetch: int = 4,
        sequence_length: int = 1,
        batches_per_message: Optional[int] = None,
    ) -> SampleStream | OnDemandStream:
        """An endless iterator of batches, fetched ahead by a background thread; with
        `prefetch=0`, each batch is drawn only when asked for (`OnDemandStream`). See
        `SampleStream` for `batches_per_message`."""
        if prefetch == 0:
            return OnDemandStream(self, table, batch_size, sequence_length=sequence_length)
        return SampleStream(
            self,
            table,
            batch_size,
            prefetch=prefetch,
            sequence_length=sequence_length,
            batches_per_message=batches_per_message,
        )

    def update_priorities(self, table: str, keys: np.ndarray, priorities: np.ndarray) -> int:
        """Sets priorities by item key (from a sample's `_key`); returns how many were live."""
        request = replay_pb2.UpdatePrioritiesRequest(
            table=table,
            keys=np.asarray(keys, dtype=np.uint64).reshape(-1).tolist(),
            priorities=np.asarray(priorities, dtype=np.float64).reshape(-1).tolist(),
        )
        try:
            response: replay_pb2.UpdatePrioritiesResponse = self.stub.UpdatePriorities(
                request, metadata=self._metadata
            )
            return response.updated
        except grpc.RpcError as error:
            raise typed(error) from None

    def checkpoint(self) -> str:
        """Asks the server to write a checkpoint now; returns its path."""
        try:
            response: replay_pb2.CheckpointResponse = self.stub.Checkpoint(
                replay_pb2.CheckpointRequest(), metadata=self._metadata
            )
            return response.path
        except grpc.RpcError as error:
            raise typed(error) from None

    def info(self) -> list[TableStatus]:
        try:
            response = self.stub.Info(replay_pb2.InfoRequest(), metadata=self._metadata)
        except grpc.RpcError as error:
            raise typed(error) from None
        return [
            TableStatus(
                name=t.name,
                size=t.size,
                max_size=t.max_size,
                inserts=t.inserts,
                samples=t.samples,
                sampler=t.sampler,
                remover=t.remover,
                rate_limiter=t.rate_limiter,
                signature=json.loads(t.signature_json),
                bytes_in_memory=t.bytes_in_memory,
                rate_limiter_blocked_s=t.rate_limiter_blocked_s,
                bytes_used=t.bytes_used,
                memory_budget_bytes=response.memory_budget_bytes,
                memory_budget=response.memory_budget,
            )
            for t in response.tables
        ]

    def wait_until_ready(self, timeout: float = 30.0) -> None:
        """Blocks until the server answers a call of this client (its TLS, its token).

        Raises:
            Unavailable: no answer within `timeout` seconds.
            Unauthenticated: the server answers, but refuses this client's token.
        """
        try:
            self.stub.Info(
                replay_pb2.InfoRequest(),
                metadata=self._metadata,
                timeout=timeout,
                wait_for_ready=True,
            )
        except grpc.RpcError as error:
            if error.code() == grpc.StatusCode.DEADLINE_EXCEEDED:
                raise Unavailable(
                    f"replay server at {self.address} did not answer in {timeout}s"
                ) from None
            raise typed(error) from None


def _rebuild_client(
    address: str,
    token: Optional[str],
    max_retries: int,
    max_message_bytes: int,
    tls_root_cert: Optional[str],
) -> ReplayClient:
    return ReplayClient(
        address,
        token=token,
        max_retries=max_retries,
        max_message_bytes=max_message_bytes,
        tls_root_cert=tls_root_cert,
    )


class _SampleCall(Protocol):
    """A streaming Sample call: its responses, and a way to end it."""

    def __iter__(self) -> Iterator[replay_pb2.SampleResponse]: ...
    def cancel(self) -> bool: ...


_Sampled = Union[tuple[list[Batch], int, int], ReplayError, None]
"""What the prefetch thread hands over: (the batches of one response, table_inserts,
table_size), an error, or None once the stream has ended."""


class SampleStream:
    """Batches prefetched over one bidirectional stream with credit-based flow control.

    The client grants the server `prefetch` batches up front and, as it consumes them,
    grants them again `batches_per_message` at a time (default: half the prefetch, so
    one message is in flight while the other is consumed). The server never samples more
    than `prefetch` batches ahead: the table's rate limiter then sees the learner's true
    pace. It stacks up to `batches_per_message` batches into one response, each admitted
    and counted by the rate limiter on its own, so the fixed cost of a message is paid
    once for several batches. `wait_s` adds up the time the consumer waited for a batch
    (time lost to the replay server). If the server becomes UNAVAILABLE (restart), the
    stream reconnects with backoff. `on_arrival` is called (from the prefetch thread)
    after each response arrives, so a consumer of several streams can wait for
    whichever is `ready()` first.
    """

    def __init__(
        self,
        client: ReplayClient,
        table: str,
        batch_size: int,
        *,
        prefetch: int,
        sequence_length: int = 1,
        batches_per_message: Optional[int] = None,
        on_arrival: Optional[Callable[[], None]] = None,
    ) -> None:
        self.table_inserts = 0
        self.table_size = 0
        self.seen_inserts = 0
        """The table's inserts as of the newest batch received (consumed or not)."""
        self.seen_size = 0
        """The table's size as of the newest batch received (consumed or not)."""
        self.wait_s = 0.0
        self._on_arrival = on_arrival
        self._client = client
        self._prefetch = max(prefetch, 1)
        per_message = self._prefetch // 2 if batches_per_message is None else batches_per_message
        self._per_message = min(max(per_message, 1), self._prefetch)
        self._consumed = 0
        """Batches consumed since credits were last granted."""
        self._batches: queue.Queue[_Sampled] = queue.Queue()
        self._ready: deque[Batch] = deque()
        """Batches of a received response not yet consumed."""
        self._request = replay_pb2.SampleRequest(
            table=table,
            batch_size=batch_size,
            num_batches=self._per_message,
            sequence_length=sequence_length,
            batches_per_message=self._per_message,
        )
        self._closed = threading.Event()
        self._credits: queue.Queue[Optional[replay_pb2.SampleRequest]] = queue.Queue()
        self._call = self._open()
        self._thread = threading.Thread(target=self._pump, daemon=True, name="replay-prefetch")
        self._thread.start()

    def _open(self) -> _SampleCall:
        """A new call, granted a full prefetch window (batches in flight were lost with the old)."""
        credits: queue.Queue[Optional[replay_pb2.SampleRequest]] = queue.Queue()
        first = replay_pb2.SampleRequest()
        first.CopyFrom(self._request)
        first.num_batches = self._prefetch
        credits.put(first)
        self._credits = credits

        def requests() -> Iterator[replay_pb2.SampleRequest]:
            while (request := credits.get()) is not None:
                yield request

        call: _SampleCall = self._client.stub.Sample(requests(), metadata=self._client._metadata)
        return call

    def _pump(self) -> None:
        attempt = 0
        while not self._closed.is_set():
            try:
                for response in self._call:
                    attempt = 0
                    batch = decode_batch(response.batch, max_bytes=self._client.max_message_bytes)
                    batches = split_batch(batch, max(response.num_batches, 1))
                    self.seen_inserts, self.seen_size = response.table_inserts, response.table_size
                    self._put((batches, response.table_inserts, response.table_size))
                break
            except CodecError as error:
                self._put(ReplayError(f"the server sent a malformed sample response: {error}"))
                self._call.cancel()
                break
            except grpc.RpcError as error:
                if self._closed.is_set() or error.code() == grpc.StatusCode.CANCELLED:
                    break
                if (
                    error.code() != grpc.StatusCode.UNAVAILABLE
                    or attempt >= self._client.max_retries
                ):
                    self._put(typed(error))
                    break
                time.sleep(min(0.05 * 2**attempt, 2.0))
                attempt += 1
                self._call = self._open()
        self._put(None)

    def _put(self, item: _Sampled) -> None:
        self._batches.put(item)
        if self._on_arrival is not None:
            self._on_arrival()

    def ready(self) -> bool:
        """A batch (or the stream's end, or its error) waits to be taken: `next_within(0)`
        returns it at once."""
        return bool(self._ready) or not self._batches.empty()

    def __iter__(self) -> Iterator[Batch]:
        return self

    def __next__(self) -> Batch:
        return self.next_within(None)

    def next_within(self, timeout: Optional[float]) -> Batch:
        """The next batch; raises TimeoutError if none arrives within `timeout` seconds."""
        if not self._ready:
            start = time.perf_counter()
            try:
                item = self._batches.get(timeout=timeout)
            except queue.Empty:
                raise TimeoutError(f"no sampled batch within {timeout} s") from None
            finally:
                self.wait_s += time.perf_counter() - start
            if item is None:
                self._batches.put(None)  # stay exhausted
                raise StopIteration
            if isinstance(item, ReplayError):
                raise item
            batches, self.table_inserts, self.table_size = item
            self._ready.extend(batches)
        self._consumed += 1
        if self._consumed == self._per_message:  # consumed: granted again, in one request
            self._credits.put(self._request)
            self._consumed = 0
        return self._ready.popleft()

    def close(self) -> None:
        self._closed.set()
        self._credits.put(None)
        self._call.cancel()


class OnDemandStream:
    """Batches drawn one at a time, each only when the consumer asks for it: nothing is
    sampled ahead, so every draw sees the table exactly as the consumer's own order of
    inserts and samples left it (the reproducible mode's lock-step learner)."""

    def __init__(
        self, client: ReplayClient, table: str, batch_size: int, *, sequence_length: int = 1
    ) -> None:
        self.table_inserts = 0
        self.table_size = 0
        self.wait_s = 0.0
        self._client = client
        self._args = (table, batch_size, sequence_length)

    def __iter__(self) -> Iterator[Batch]:
        return self

    def __next__(self) -> Batch:
        return self.next_within(None)

    def next_within(self, timeout: Optional[float]) -> Batch:
        """The next batch; raises TimeoutError if the table admits none within `timeout` s."""
        start = time.perf_counter()
        try:
            response = self._client._sample_once(*self._args, timeout)
        except DeadlineExceeded:
            raise TimeoutError(f"no sampled batch within {timeout} s") from None
        finally:
            self.wait_s += time.perf_counter() - start
        self.table_inserts, self.table_size = response.table_inserts, response.table_size
        return decode_batch(response.batch, max_bytes=self._client.max_message_bytes)

    def close(self) -> None:
        pass
