"""Several replay servers as one: writers are routed to a shard, samples drawn across shards.

Each writer always inserts into the same shard (its `home`: given, or chosen from its
writer id), so its batches stay in order and its episodes, and the windows cut from
them, stay whole. A sampled batch comes from one shard chosen with probability
proportional to the shard's size, so every stored item is equally likely overall;
a stream chooses among the shards that have a batch ready, so a shard whose rate
limiter holds samples back never stalls the learner while another shard has one.
Keys carry their shard in the top byte, so priority updates find their way back.

Each shard's rate limiter sees only its own inserts and samples. Its ratio is the
preset's, and its error buffer, minimum size and sample credit are the preset's shares
(`graft/replay_host/shards.py` splits them), so the sums over shards hold the preset's
samples-per-insert ratio overall (see `ShardedSampleStream`).
"""

from __future__ import annotations

import threading
import time
import uuid
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Optional

import numpy as np

from service.replay.client import ReplayClient, SampleStream, TableStatus
from service.replay.codec import Batch

SHARD_SHIFT = np.uint64(56)
KEY_MASK = np.uint64((1 << 56) - 1)


class ShardedReplayClient:
    """The ReplayClient interface over `addresses`; pickles as its addresses, retries and home.

    Args:
        addresses: "host:port" of each shard, in shard order.
        token: shared secret of servers bound beyond loopback.
        writer_id: this writer's id on every shard (default: a fresh one).
        seed: seeds the choice of shard per sampled batch.
        max_retries: retries of an UNAVAILABLE call per shard (`ReplayClient`).
        home: the shard this writer inserts into (default: from its writer id); a run
            gives actor i shard i mod N, so every shard has writers.
    """

    def __init__(
        self,
        addresses: Sequence[str],
        *,
        token: Optional[str] = None,
        writer_id: Optional[str] = None,
        seed: Optional[int] = None,
        max_retries: int = 8,
        home: Optional[int] = None,
    ) -> None:
        if not addresses:
            raise ValueError("a sharded client needs at least one address")
        if len(addresses) > 255:
            raise ValueError("at most 255 shards: the shard index lives in the key's top byte")
        if home is not None and not 0 <= home < len(addresses):
            raise ValueError(f"home={home} must lie in [0, {len(addresses) - 1}]")
        self.addresses = list(addresses)
        self.token = token
        self.max_retries = max_retries
        self.writer_id = writer_id or uuid.uuid4().hex
        self.shards = [
            ReplayClient(a, token=token, writer_id=self.writer_id, max_retries=max_retries)
            for a in addresses
        ]
        self._home = home
        self.home = (
            home if home is not None else zlib.crc32(self.writer_id.encode()) % len(self.shards)
        )
        self._rng = np.random.default_rng(seed)

    def __reduce__(self) -> tuple[Callable[..., ShardedReplayClient], tuple[Any, ...]]:
        return (_rebuild, (self.addresses, self.token, self.max_retries, self._home))

    def insert(
        self, table: str, columns: Mapping[str, np.ndarray], *, timeout: Optional[float] = None
    ) -> int:
        """Inserts into this writer's home shard."""
        return self.shards[self.home].insert(table, columns, timeout=timeout)

    def _sizes(self, table: str) -> np.ndarray:
        return np.array(
            [next(t.size for t in s.info() if t.name == table) for s in self.shards], float
        )

    def _tag(self, batch: Batch, shard: int) -> Batch:
        batch = dict(batch)
        batch["_key"] = batch["_key"].astype(np.uint64) | (np.uint64(shard) << SHARD_SHIFT)
        return batch

    def sample(self, table: str, batch_size: int, *, sequence_length: int = 1,
               timeout: Optional[float] = None) -> Batch:  # fmt: skip
        sizes = self._sizes(table)
        if sizes.sum() == 0:
            shard = int(self._rng.integers(len(self.shards)))
        else:
            shard = int(self._rng.choice(len(self.shards), p=sizes / sizes.sum()))
        batch = self.shards[shard].sample(
            table, batch_size, sequence_length=sequence_length, timeout=timeout
        )
        return self._tag(batch, shard)

    def sample_stream(self, table: str, batch_size: int, *, prefetch: int = 4,
                      sequence_length: int = 1) -> ShardedSampleStream:  # fmt: skip
        """Batches from every shard (`ShardedSampleStream`); `prefetch` batches in flight
        over all shards (at least one per shard: prefetch 0 is taken as 1 per shard)."""
        return ShardedSampleStream(
            self, table, batch_size, prefetch=prefetch, sequence_length=sequence_length
        )

    def update_priorities(self, table: str, keys: np.ndarray, priorities: np.ndarray) -> int:
        keys = np.asarray(keys, dtype=np.uint64).reshape(-1)
        priorities = np.asarray(priorities, dtype=np.float64).reshape(-1)
        shard_of = (keys >> SHARD_SHIFT).astype(np.int64)
        updated = 0
        for shard in np.unique(shard_of).tolist():
            mine = shard_of == shard
            updated += self.shards[shard].update_priorities(
                table, keys[mine] & KEY_MASK, priorities[mine]
            )
        return updated

    def info(self) -> list[list[TableStatus]]:
        """Per shard, its tables."""
        return [s.info() for s in self.shards]

    def close(self) -> None:
        for s in self.shards:
            s.close()


class ShardedSampleStream:
    """Prefetching streams from every shard; each batch comes from a shard that has one
    ready, chosen with probability proportional to the shard's size.

    Why among the ready ones: every shard's rate limiter admits samples only as its own
    inserts arrive. Blocking on a size-chosen shard whose actors are behind would stall
    the learner while another shard has batches waiting. Choosing among ready shards,
    the learner's samples follow what each limiter admits, so every shard holds the
    ratio within its error buffer and, summed, the whole replay holds it within the
    preset's buffer. While no limiter holds (all ready), the choice is proportional to
    size: uniform over every stored item, as one server would sample. Sizes come with
    each batch received (`SampleStream.seen_size`); a shard that has sent nothing yet is
    below its minimum size and not ready anyway.
    """

    def __init__(
        self,
        client: ShardedReplayClient,
        table: str,
        batch_size: int,
        *,
        prefetch: int,
        sequence_length: int = 1,
    ) -> None:
        self._client = client
        self._arrived = threading.Condition()
        each = max(-(-prefetch // len(client.shards)), 1)
        self._streams = [
            SampleStream(
                shard,
                table,
                batch_size,
                prefetch=each,
                sequence_length=sequence_length,
                on_arrival=self._wake,
            )
            for shard in client.shards
        ]
        self.wait_s = 0.0
        self.table_size = 0
        self.table_inserts = 0
        """Items inserted over all shards, as of each shard's newest batch."""

    def _wake(self) -> None:
        with self._arrived:
            self._arrived.notify_all()

    @property
    def shard_sizes(self) -> list[int]:
        """Each shard's table size, as of its newest batch."""
        return [s.seen_size for s in self._streams]

    def __iter__(self) -> Iterator[Batch]:
        return self

    def __next__(self) -> Batch:
        return self.next_within(None)

    def next_within(self, timeout: Optional[float]) -> Batch:
        """The next batch; raises TimeoutError if no shard has one within `timeout` s."""
        start = time.perf_counter()
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            with self._arrived:
                while not (ready := [k for k, s in enumerate(self._streams) if s.ready()]):
                    remaining = None if deadline is None else deadline - time.monotonic()
                    if remaining is not None and remaining <= 0:
                        raise TimeoutError(f"no sampled batch within {timeout} s")
                    self._arrived.wait(remaining)
        finally:
            self.wait_s += time.perf_counter() - start
        sizes = np.array([max(self._streams[k].seen_size, 1) for k in ready], float)
        shard = ready[int(self._client._rng.choice(len(ready), p=sizes / sizes.sum()))]
        batch = self._streams[shard].next_within(0)  # ready: returns at once
        self.table_size = sum(self.shard_sizes)
        self.table_inserts = sum(s.seen_inserts for s in self._streams)
        return self._client._tag(batch, shard)

    def close(self) -> None:
        for s in self._streams:
            s.close()


def _rebuild(
    addresses: list[str], token: Optional[str], max_retries: int, home: Optional[int]
) -> ShardedReplayClient:
    return ShardedReplayClient(addresses, token=token, max_retries=max_retries, home=home)
