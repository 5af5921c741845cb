"""Several replay servers as one: writers are routed to a shard, samples drawn across shards.

Each writer always inserts into the same shard (chosen from its writer id), so its
batches stay in order and its episodes, and the windows cut from them, stay whole.
A sampled batch comes from one shard chosen with probability proportional to the
shard's size, so every stored item is equally likely overall. Keys carry their shard
in the top byte, so priority updates find their way back.
"""

from __future__ import annotations

import uuid
import zlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, Optional

import numpy as np

from service.replay.client import OnDemandStream, ReplayClient, SampleStream, TableStatus
from service.replay.codec import Batch

SHARD_SHIFT = np.uint64(56)
KEY_MASK = np.uint64((1 << 56) - 1)


class ShardedReplayClient:
    """The ReplayClient interface over `addresses`; pickles as its addresses."""

    def __init__(
        self,
        addresses: Sequence[str],
        *,
        token: Optional[str] = None,
        writer_id: Optional[str] = None,
        seed: Optional[int] = None,
    ) -> None:
        if not addresses:
            raise ValueError("a sharded client needs at least one address")
        if len(addresses) > 255:
            raise ValueError("at most 255 shards: the shard index lives in the key's top byte")
        self.addresses = list(addresses)
        self.token = token
        self.writer_id = writer_id or uuid.uuid4().hex
        self.shards = [ReplayClient(a, token=token, writer_id=self.writer_id) for a in addresses]
        self.home = zlib.crc32(self.writer_id.encode()) % len(self.shards)
        self._rng = np.random.default_rng(seed)

    def __reduce__(self) -> tuple[Callable[..., ShardedReplayClient], tuple[Any, ...]]:
        return (_rebuild, (self.addresses, self.token))

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
        streams = [
            s.sample_stream(table, batch_size, prefetch=prefetch, sequence_length=sequence_length)
            for s in self.shards
        ]
        return ShardedSampleStream(self, streams, self._sizes(table))

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
    """Prefetching streams from every shard; each batch comes from a size-weighted shard."""

    def __init__(
        self,
        client: ShardedReplayClient,
        streams: list[SampleStream | OnDemandStream],
        sizes: np.ndarray,
    ) -> None:
        self._client, self._streams = client, streams
        self._sizes = np.maximum(sizes, 0.0)

    @property
    def wait_s(self) -> float:
        return sum(s.wait_s for s in self._streams)

    @property
    def table_inserts(self) -> int:
        return sum(s.table_inserts for s in self._streams)

    def __iter__(self) -> Iterator[Batch]:
        return self

    def __next__(self) -> Batch:
        total = self._sizes.sum()
        p = self._sizes / total if total > 0 else None
        shard = int(self._client._rng.choice(len(self._streams), p=p))
        batch = next(self._streams[shard])
        # Keep the weights current: each response reports its shard's size.
        self._sizes[shard] = max(self._streams[shard].table_size, 1)
        return self._client._tag(batch, shard)

    def close(self) -> None:
        for s in self._streams:
            s.close()


def _rebuild(addresses: list[str], token: Optional[str]) -> ShardedReplayClient:
    return ShardedReplayClient(addresses, token=token)
