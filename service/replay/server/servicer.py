"""The replay gRPC servicer: a thin asynchronous layer over ReplayCore.

Each handler decodes, validates (service/replay/server/request_limits.py), calls the
core and encodes; one map turns the core's errors into gRPC statuses. A call that waits
(on a rate limiter, on a claim) is a parked coroutine holding no thread. Table work runs
briefly: inline when small and its locks are free, else on a bounded thread pool.
"""

from __future__ import annotations

import asyncio
import functools
import time
from collections.abc import AsyncIterator, Callable
from concurrent import futures
from typing import Any, Optional, TypeVar

import grpc
import numpy as np

from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.codec import (
    DEFAULT_MAX_BYTES,
    CodecError,
    PayloadTooLarge,
    decode_batch,
    encode_batch,
)
from service.replay.server.durability import StorageError
from service.replay.server.request_limits import (
    batches_per_message,
    check_insert,
    check_sample,
    check_table_name,
)
from service.replay.server.rpc_meter import RpcMeter
from service.replay.server.signature import SignatureError
from service.replay.server.store import CallEnded, ReplayCore, StagedInsert, UnknownTable
from service.replay.server.table import LockBusy, RateLimitTimeout, Table
from service.replay.server.waiting import CallState, Wakeups, wait_for_change
from service.replay.server.writers import Claim

INLINE_BYTES = 256 * 1024
"""Table work on at most this many bytes runs on the event loop if its locks are free:
a hop to the pool and back costs more than the work. Larger work, work that meets a
held lock, and inserts that fsync run on the pool."""

T = TypeVar("T")

_STATUS_OF = (
    (PayloadTooLarge, grpc.StatusCode.RESOURCE_EXHAUSTED),
    (UnknownTable, grpc.StatusCode.NOT_FOUND),
    ((RateLimitTimeout, CallEnded), grpc.StatusCode.DEADLINE_EXCEEDED),
    (StorageError, grpc.StatusCode.UNAVAILABLE),  # e.g. a full disk; a resend may succeed
    ((CodecError, SignatureError, ValueError), grpc.StatusCode.INVALID_ARGUMENT),
)


def _earlier(a: Optional[float], b: Optional[float]) -> Optional[float]:
    return b if a is None else a if b is None else min(a, b)


class ReplayServicer(replay_pb2_grpc.ReplayServiceServicer):
    """Decode, validate, call the core, encode. Nothing else lives here.

    Every count a request carries is checked against the table and the message limit
    before anything is allocated. An Insert stream is stored whole when it ends, or
    not at all; a batch waiting on the rate limiter holds its (writer, sequence) claim.
    """

    def __init__(
        self,
        core: ReplayCore,
        meter: RpcMeter,
        *,
        loop: asyncio.AbstractEventLoop,
        pool: futures.Executor,
        max_message_bytes: int = DEFAULT_MAX_BYTES,
        ended_badly: Callable[[], None] = lambda: None,
    ) -> None:
        """`ended_badly` is called (on the event loop) for each call refused or aborted."""
        self.core = core
        self._ended_badly = ended_badly
        self.meter = meter
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

    def _refuse(self, context: grpc.aio.ServicerContext[Any, Any], error: Exception) -> None:
        """Sets the status a client can act on for a core exception; re-raises the unknown.

        The handler then returns: `context.abort` would raise an exception that the call's
        state keeps, whose traceback holds the handler's frame and so the request, in a
        reference cycle only the cyclic garbage collector frees. Refused megabyte requests
        then pile up faster than it runs, and the freed memory stays fragmented."""
        self._ended_badly()  # what the call leaves is handed back (allocator.FreedMemory)
        for kinds, code in _STATUS_OF:
            if isinstance(error, kinds):
                self.meter.refused(code.name)
                context.set_code(code)
                context.set_details(str(error))
                return
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
                self.meter.received(len(request.batch))
                stream_batches += 1
                stream_bytes += len(request.batch)
                table = check_insert(
                    self.core,
                    request,
                    stream_batches,
                    stream_bytes,
                    max_message_bytes=self.max_message_bytes,
                )
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
            self._ended_badly()
            raise
        except Exception as error:
            self._refuse(context, error)
            return replay_pb2.InsertResponse()
        finally:
            self.core.writers.release(call, claimed)
            self._wakeups.wake(Wakeups.CLAIMS)
        self.meter.handled("Insert", time.perf_counter() - start)
        return replay_pb2.InsertResponse(
            items_inserted=stored,
            batches_dropped_as_duplicates=dropped,
            acked_sequence={w: self.core.writers.acked(w) for w in writers},
        )

    # ----------------------------------------------------------------- Sample

    @staticmethod
    def _sample_once(
        table: Table,
        request: replay_pb2.SampleRequest,
        count: int,
        call: CallState,
        waited: float,
        *,
        blocking: bool = True,
    ) -> Optional[tuple[bytes, int]]:
        """One attempt: up to `count` batches the limiter admits now, encoded stacked, and
        how many; None while it admits none."""
        if not call.alive():
            raise CallEnded("the call was cancelled or passed its deadline")
        sampled = table.try_sample_batches(
            request.batch_size,
            count,
            sequence_length=max(request.sequence_length, 1),
            blocked_s=waited,
            blocking=blocking,
        )
        return None if sampled is None else (encode_batch(sampled[0]), sampled[1])

    async def Sample(  # noqa: N802
        self,
        request_iterator: AsyncIterator[replay_pb2.SampleRequest],
        context: grpc.aio.ServicerContext[Any, Any],
    ) -> AsyncIterator[replay_pb2.SampleResponse]:
        call = CallState(context)
        try:
            async for request in request_iterator:  # each request grants num_batches credits
                table = check_sample(self.core, request, max_message_bytes=self.max_message_bytes)
                k = max(request.sequence_length, 1)
                batch_bytes = table.sampled_bytes(request.batch_size, k)
                most = batches_per_message(table, request, max_message_bytes=self.max_message_bytes)
                credits = max(request.num_batches, 1)
                while credits:
                    start = time.perf_counter()
                    deadline = call.deadline_with(request.timeout_s)
                    count = min(credits, most)
                    payload, sent = await self._until(
                        (table.name,),
                        functools.partial(self._sample_once, table, request, count, call),
                        deadline,
                        inline=batch_bytes * count <= INLINE_BYTES,
                        table=table,
                        what="sample",
                    )
                    credits -= sent
                    self.meter.sent(len(payload))
                    self.meter.handled("Sample", time.perf_counter() - start)
                    yield replay_pb2.SampleResponse(
                        batch=payload,
                        table_inserts=table.stats.inserts,
                        table_size=table.size,
                        num_batches=sent,
                    )
        except asyncio.CancelledError:
            call.end()
            self._ended_badly()
            raise
        except Exception as error:
            self._refuse(context, error)

    # ------------------------------------------------------------------ other

    async def UpdatePriorities(  # noqa: N802
        self,
        request: replay_pb2.UpdatePrioritiesRequest,
        context: grpc.aio.ServicerContext[Any, Any],
    ) -> replay_pb2.UpdatePrioritiesResponse:
        try:
            check_table_name(request.table)
            table = self.core.table(request.table)
            updated = await self._run(
                table.update_priorities,
                np.asarray(request.keys, dtype=np.uint64).astype(np.int64),
                np.asarray(request.priorities, dtype=np.float64),
            )
        except Exception as error:
            self._refuse(context, error)
            return replay_pb2.UpdatePrioritiesResponse()
        return replay_pb2.UpdatePrioritiesResponse(updated=updated)

    async def Checkpoint(  # noqa: N802
        self, request: replay_pb2.CheckpointRequest, context: grpc.aio.ServicerContext[Any, Any]
    ) -> replay_pb2.CheckpointResponse:
        try:
            path = await self._run(self.core.checkpoint)
        except Exception as error:
            self._refuse(context, error)
            return replay_pb2.CheckpointResponse()
        if path is None:
            context.set_code(grpc.StatusCode.FAILED_PRECONDITION)
            context.set_details(
                "this server has no checkpoint folder (start it with --checkpoint-dir)"
            )
            return replay_pb2.CheckpointResponse()
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
                    bytes_used=t.bytes_used,
                    rate_limiter_blocked_s=t.stats.insert_blocked_s + t.stats.sample_blocked_s,
                )
            )
        budget = self.core.memory_budget
        return replay_pb2.InfoResponse(
            tables=tables,
            uptime_s=time.monotonic() - self.core.started,
            memory_budget_bytes=budget.bytes if budget else 0,
            memory_budget=budget.source if budget else "",
        )
