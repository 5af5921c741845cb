"""Exactly-once bookkeeping: per writer, the highest batch sequence stored, and the
(writer, sequence) pairs claimed by calls still in flight.

A writer numbers its batches 1, 2, 3, ... and resends a batch with the same number
when an acknowledgement is lost. A call claims its (writer, sequence) before it waits
on anything (the rate limiter, the rest of its stream), so a resend arriving on another
connection waits for the first call's outcome instead of storing the batch a second time.
The store re-checks the high-water mark under its lock, so a claim is only a courtesy
between calls; the re-check is the guarantee.

The map is bounded: past `max_writers`, the writer that stored least recently is
forgotten. A forgotten writer that later resends its last unacknowledged batch has it
stored again, so the bound must exceed the number of writers that are active at once
(each `ReplayClient` object is one writer).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterable
from enum import Enum

DEFAULT_MAX_WRITERS = 100_000
MAX_WRITER_ID_BYTES = 256


class Claim(Enum):
    """What `Writers.claim` found."""

    CLAIMED = "claimed"
    """The caller holds the (writer, sequence) now."""
    STORED = "stored"
    """The batch is already stored: a resend to drop."""
    BUSY = "busy"
    """Another call holds it; wait for that call to end, then claim again."""


class Writers:
    """Acknowledged sequences (least recently stored first) and in-flight claims; thread-safe."""

    def __init__(self, max_writers: int = DEFAULT_MAX_WRITERS) -> None:
        if max_writers < 1:
            raise ValueError(f"max_writers must be >= 1, got {max_writers}")
        self.max_writers = max_writers
        self._acked: OrderedDict[str, int] = OrderedDict()
        self._claims: dict[tuple[str, int], object] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._acked)

    def acked(self, writer: str) -> int:
        """The highest sequence stored for `writer` (0: none, or forgotten)."""
        return self._acked.get(writer, 0)

    def ack(self, writer: str, sequence: int) -> None:
        """Records a stored batch; forgets the least recently stored writer past the bound."""
        with self._lock:
            self._acked[writer] = max(sequence, self._acked.get(writer, 0))
            self._acked.move_to_end(writer)
            while len(self._acked) > self.max_writers:
                self._acked.popitem(last=False)

    def claim(self, writer: str, sequence: int, owner: object) -> Claim:
        """Claims (writer, sequence) for `owner` (one call) unless stored or held by another."""
        with self._lock:
            if sequence <= self._acked.get(writer, 0):
                return Claim.STORED
            holder = self._claims.setdefault((writer, sequence), owner)
            return Claim.CLAIMED if holder is owner else Claim.BUSY

    def release(self, owner: object, keys: Iterable[tuple[str, int]]) -> None:
        """Gives up `owner`'s claims on `keys` (whether or not it stored them)."""
        with self._lock:
            for key in keys:
                if self._claims.get(key) is owner:
                    del self._claims[key]

    def snapshot(self) -> dict[str, int]:
        """The map, least recently stored writer first (the order survives a checkpoint)."""
        with self._lock:
            return dict(self._acked)

    def restore(self, acked: dict[str, int]) -> None:
        """Loads a `snapshot`, keeping the `max_writers` most recent."""
        with self._lock:
            self._acked = OrderedDict(acked)
            while len(self._acked) > self.max_writers:
                self._acked.popitem(last=False)
