"""Sends an actor's insert batches to the replay server from a background thread, so
acting does not wait on the network; how far acting may run ahead is bounded.

    writer = BackgroundWriter(replay)
    writer.insert("transitions", batch, max_pending=8)   # returns once <= 8 batches wait
    writer.insert("transitions", batch, max_pending=0)   # returns once this one is stored
    writer.flush()                                       # everything stored
    writer.close()

Back-pressure, never loss: ``insert`` returns while at most ``max_pending`` batches are
not yet acknowledged by the server, else it waits for room. A table whose rate limiter
holds inserts back (samples per insert) therefore still holds the actor back, with at
most ``max_pending`` batches of slack; ``max_pending=0`` waits for each insert, exactly
as an insert on the acting thread would. No batch is ever dropped.

Errors surface: an insert that failed in the background (the server gone, a refused
batch) is raised again by the next ``insert`` or ``flush`` on the acting thread, and
nothing after it is sent.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable, Mapping
from typing import Optional

import numpy as np

from service.core import ReplayWriter


class BackgroundWriter:
    """One actor's background inserter (FIFO: batches are stored in the order given).

    Args:
        replay: client of the replay server; only the writer's thread inserts with it.
    """

    def __init__(self, replay: ReplayWriter) -> None:
        self.replay = replay
        self.inserted = 0
        """Items the server acknowledged."""
        self.insert_s = 0.0
        """Time the sender spent in acknowledged insert calls (including rate-limiter holds)."""
        self.insert_calls = 0
        """Insert calls the server acknowledged."""
        self.fastest_insert_s = float("inf")
        """The quickest acknowledged insert call: about the network and server cost of one
        batch that no rate limiter held."""
        self.wait_s = 0.0
        """Time callers of ``insert``/``flush`` waited for the sender."""
        self._queue: collections.deque[tuple[str, Mapping[str, np.ndarray]]] = collections.deque()
        self._in_flight = 0
        self._error: Optional[BaseException] = None
        self._waiting_since: Optional[float] = None
        self._calling_since: Optional[float] = None
        self._closing = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._send_loop, name="replay-writer", daemon=True)
        self._thread.start()

    def waited_s(self) -> float:
        """`wait_s` including a wait still in progress (a rate limiter may hold one insert
        longer than a measurement window)."""
        since = self._waiting_since
        return self.wait_s + (time.perf_counter() - since if since is not None else 0.0)

    def insert_call_s(self) -> float:
        """`insert_s` including a call still in progress, for the same reason."""
        with self._cond:
            since, done = self._calling_since, self.insert_s
        return done + (time.perf_counter() - since if since is not None else 0.0)

    def pending(self) -> int:
        """Batches given to ``insert`` and not yet acknowledged."""
        with self._cond:
            return len(self._queue) + self._in_flight

    def insert(self, table: str, batch: Mapping[str, np.ndarray], *, max_pending: int) -> None:
        """Queue ``batch`` for ``table``; wait while more than ``max_pending`` batches
        (this one included) are unacknowledged.

        Raises:
            ValueError: ``max_pending`` is negative.
            Exception: the error of an earlier background insert.
        """
        if max_pending < 0:
            raise ValueError(f"max_pending={max_pending} must be >= 0 (0: wait for each insert)")
        with self._cond:
            self._raise_error()
            if self._closing:
                raise RuntimeError("the writer is closed")
            self._queue.append((table, batch))
            self._cond.notify_all()
            self._wait(lambda: len(self._queue) + self._in_flight <= max_pending, None)

    def flush(self, timeout_s: Optional[float] = None) -> None:
        """Wait until every queued batch is stored.

        Raises:
            TimeoutError: batches still wait after ``timeout_s`` seconds.
            Exception: the error of a background insert.
        """
        with self._cond:
            if not self._wait(lambda: not self._queue and not self._in_flight, timeout_s):
                raise TimeoutError(
                    f"{len(self._queue) + self._in_flight} insert batches still unacknowledged "
                    f"after {timeout_s} s: is the table's rate limiter holding them (no learner "
                    "sampling)?"
                )

    def close(self, timeout_s: Optional[float] = None) -> None:
        """Flush, then stop the sender thread."""
        try:
            self.flush(timeout_s)
        finally:
            with self._cond:
                self._closing = True
                self._cond.notify_all()
            self._thread.join(timeout_s)

    def _wait(self, done: Callable[[], bool], timeout_s: Optional[float]) -> bool:
        # Called holding the condition; raises a background error as soon as it appears.
        t0 = self._waiting_since = time.perf_counter()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        try:
            while not done():
                self._raise_error()
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return False
                self._cond.wait(remaining)
            self._raise_error()
            return True
        finally:
            self.wait_s += time.perf_counter() - t0
            self._waiting_since = None

    def _raise_error(self) -> None:
        if self._error is not None:
            raise self._error

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue or self._error is not None:
                    return
                table, batch = self._queue.popleft()
                self._in_flight = 1
                t = self._calling_since = time.perf_counter()
            try:
                stored = self.replay.insert(table, batch)
            except Exception as e:  # handed to the acting thread, raised there
                with self._cond:
                    self._error = e
                    self._in_flight = 0
                    self._calling_since = None
                    self._queue.clear()
                    self._cond.notify_all()
                return
            took = time.perf_counter() - t
            with self._cond:
                self.insert_s += took
                self._calling_since = None
                self.insert_calls += 1
                self.fastest_insert_s = min(self.fastest_insert_s, took)
                self.inserted += stored
                self._in_flight = 0
                self._cond.notify_all()
