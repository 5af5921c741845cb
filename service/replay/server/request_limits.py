"""Bounds on what a client may send, checked before anything is allocated.

Each refusal names the field and the limit; the servicer maps it to a gRPC status.
"""

from __future__ import annotations

import math

from service.replay._proto import replay_pb2
from service.replay.codec import PayloadTooLarge
from service.replay.server.store import ReplayCore
from service.replay.server.table import Table
from service.replay.server.writers import MAX_WRITER_ID_BYTES

MAX_TABLE_NAME_BYTES = 256
MAX_STREAM_BATCHES = 1024
"""Most batches one Insert stream may carry (it is held whole until it ends)."""
MAX_SAMPLE_CREDITS = 1 << 16
"""Most batches one SampleRequest may ask for (`num_batches`)."""
RESPONSE_OVERHEAD_BYTES = 64 * 1024
"""Room kept in a sample response for column headers and the message's other fields."""


def check_table_name(name: str) -> None:
    """Refuses a table name longer than `MAX_TABLE_NAME_BYTES`."""
    if len(name.encode()) > MAX_TABLE_NAME_BYTES:
        raise ValueError(f"table name is longer than the {MAX_TABLE_NAME_BYTES}-byte limit")


def check_timeout(timeout_s: float) -> None:
    """Refuses a timeout that is negative or not finite."""
    if not (math.isfinite(timeout_s) and timeout_s >= 0):
        raise ValueError(f"timeout_s must be a finite number >= 0, got {timeout_s}")


def check_insert(
    core: ReplayCore,
    request: replay_pb2.InsertRequest,
    stream_batches: int,
    stream_bytes: int,
    *,
    max_message_bytes: int,
) -> Table:
    """The table one batch of an Insert stream goes to, once the batch and the stream so
    far (`stream_batches`, `stream_bytes`) are within the limits."""
    check_table_name(request.table)
    writer_bytes = len(request.writer_id.encode())
    if writer_bytes > MAX_WRITER_ID_BYTES:
        raise ValueError(
            f"writer_id of {writer_bytes} bytes is longer than the {MAX_WRITER_ID_BYTES}-byte limit"
        )
    check_timeout(request.timeout_s)
    if stream_batches > MAX_STREAM_BATCHES or stream_bytes > max_message_bytes:
        raise PayloadTooLarge(
            f"an Insert stream carries at most {MAX_STREAM_BATCHES} batches and "
            f"{max_message_bytes} bytes (it is stored whole when it ends), this one "
            f"{stream_batches} and {stream_bytes} so far; split it into several calls"
        )
    return core.table(request.table)


def check_sample(
    core: ReplayCore, request: replay_pb2.SampleRequest, *, max_message_bytes: int
) -> Table:
    """The table a SampleRequest draws from, once its counts are within the table's and
    the message's limits (a response must fit in `max_message_bytes`)."""
    check_table_name(request.table)
    table = core.table(request.table)
    check_timeout(request.timeout_s)
    if request.num_batches > MAX_SAMPLE_CREDITS:
        raise ValueError(
            f"num_batches {request.num_batches} exceeds the limit of "
            f"{MAX_SAMPLE_CREDITS} batches per request"
        )
    k = max(request.sequence_length, 1)
    table.check_sample(request.batch_size, k)
    room = max_message_bytes - RESPONSE_OVERHEAD_BYTES
    need = table.sampled_bytes(request.batch_size, k)
    if need > room:
        raise PayloadTooLarge(
            f"batch_size {request.batch_size} x sequence_length {k} needs "
            f"{need / 2**20:.0f} MiB per response, over the "
            f"{max_message_bytes / 2**20:g} MiB message limit; ask for at most "
            f"{room // table.sampled_bytes(1, k)}"
        )
    return table


def batches_per_message(
    table: Table, request: replay_pb2.SampleRequest, *, max_message_bytes: int
) -> int:
    """How many batches one response to a (checked) SampleRequest may stack: what it asks
    for (`batches_per_message`, 0 meaning 1), within the credits limit and the message
    limit (`check_sample` has made sure one batch fits)."""
    room = max_message_bytes - RESPONSE_OVERHEAD_BYTES
    fit = room // table.sampled_bytes(request.batch_size, max(request.sequence_length, 1))
    return max(1, min(request.batches_per_message, MAX_SAMPLE_CREDITS, fit))
