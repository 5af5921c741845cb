"""Streams an actor's transitions to the replay server from a background thread, so the
real-time acting loop never waits on the network or on the replay server.

    writer = TransitionWriter(replay, "transitions", insert_every=32)
    writer.add(record)          # returns at once
    ...
    writer.close(timeout_s=10)  # flushes what is left

Transitions are grouped ``insert_every`` at a time into one insert. If the replay server
falls behind by more than ``max_pending`` batches, the oldest waiting batch is dropped
(and counted) rather than stalling the world: a Minecraft tick that passes unobserved is
lost for good, a transition dropped under overload is one sample among many.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Mapping

import numpy as np

from service.replay.client import ReplayClient, ReplayError


class TransitionWriter:
    """Background inserter for one actor.

    Args:
        replay: client of the replay server (its channel is opened in this process).
        table: table to insert into.
        insert_every: transitions per insert.
        max_pending: full batches that may wait for the sender before the oldest is dropped.
    """

    def __init__(
        self, replay: ReplayClient, table: str, *, insert_every: int = 32, max_pending: int = 64
    ) -> None:
        if insert_every < 1 or max_pending < 1:
            raise ValueError(
                f"insert_every={insert_every} and max_pending={max_pending} must be >= 1"
            )
        self.replay, self.table = replay, table
        self.insert_every, self.max_pending = insert_every, max_pending
        self.inserted = 0
        self.dropped = 0
        self.errors = 0
        self.last_error = ""
        self.insert_s = 0.0
        self._rows: list[Mapping[str, np.ndarray]] = []
        self._batches: collections.deque[dict[str, np.ndarray]] = collections.deque()
        self._cond = threading.Condition()
        self._closing = False
        self._busy = False
        self._thread = threading.Thread(target=self._send_loop, name="replay-writer", daemon=True)
        self._thread.start()

    def add(self, record: Mapping[str, np.ndarray]) -> None:
        """Queue one transition (each column a scalar or one row); never blocks on I/O."""
        self._rows.append(record)
        if len(self._rows) >= self.insert_every:
            self._enqueue()

    def _enqueue(self) -> None:
        rows, self._rows = self._rows, []
        batch = {k: np.stack([np.asarray(r[k]) for r in rows]) for k in rows[0]}
        with self._cond:
            if len(self._batches) >= self.max_pending:
                self.dropped += len(next(iter(self._batches.popleft().values())))
            self._batches.append(batch)
            self._cond.notify()

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._batches and not self._closing:
                    self._cond.wait()
                if not self._batches:
                    return
                batch = self._batches.popleft()
                self._busy = True
            t = time.perf_counter()
            try:
                self.inserted += self.replay.insert(self.table, batch)
            except ReplayError as e:  # the server is gone or refused the batch: count, go on
                self.errors += 1
                self.last_error = str(e)
            self.insert_s += time.perf_counter() - t
            with self._cond:
                self._busy = False
                self._cond.notify_all()

    def pending(self) -> int:
        """Transitions not yet acknowledged by the replay server."""
        with self._cond:
            queued = sum(len(next(iter(b.values()))) for b in self._batches)
        return len(self._rows) + queued

    def flush(self, timeout_s: float = 30.0) -> bool:
        """Send the partial batch and wait until everything queued was sent (or dropped)."""
        if self._rows:
            self._enqueue()
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._batches or self._busy:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._cond.wait(remaining)
        return True

    def close(self, timeout_s: float = 30.0) -> bool:
        """Flush, then stop the sender thread; returns whether everything was sent."""
        ok = self.flush(timeout_s)
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join(timeout_s)
        return ok
