"""Waiting without a thread: how the asynchronous replay server holds calls that wait.

A call that waits (on a rate limiter, on another call's claim, on its client's next
request) is a coroutine parked on an asyncio event, not a thread, so any number of idle
or slow streams cost no worker. Work that touches a table runs briefly (on the loop when
small and its locks are free, else on a worker thread); each attempt either succeeds or
returns None, and the call waits for the next change of what it waits on (tables report
changes through `Table.watch`).
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Optional, Protocol

RECHECK_S = 1.0
"""A waiting call re-tries at least this often, changes or not (a sampler's draw of
complete windows can fail by chance; the blocking table API re-checks as often)."""


class Wakeups:
    """Per key (a table name, or CLAIMS), the events of the calls waiting on it."""

    CLAIMS = "\0claims"
    """Key woken whenever a call gives up its (writer, sequence) claims."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._waiting: defaultdict[str, set[asyncio.Event]] = defaultdict(set)

    def notifier(self, key: str) -> Callable[[], None]:
        """A callback any thread may call after `key` changed (cheap when nobody waits)."""

        def notify() -> None:
            # A waiter registers before its attempt, so a change after an unsuccessful
            # attempt always finds it registered here.
            if self._waiting.get(key) and not self._loop.is_closed():
                self._loop.call_soon_threadsafe(self.wake, key)

        return notify

    def wake(self, key: str) -> None:
        """Wakes every call waiting on `key`; on the event loop's thread only."""
        for event in self._waiting.get(key, ()):
            event.set()

    @contextmanager
    def waiting(self, *keys: str) -> Iterator[asyncio.Event]:
        """An event set on every change of any of `keys`, while the block runs."""
        event = asyncio.Event()
        for key in keys:
            self._waiting[key].add(event)
        try:
            yield event
        finally:
            for key in keys:
                waiters = self._waiting[key]
                waiters.discard(event)
                if not waiters:
                    del self._waiting[key]


class _Context(Protocol):
    def time_remaining(self) -> Optional[float]: ...


class CallState:
    """Whether an RPC is still wanted: not cancelled, and not past its deadline.

    Worker threads read `alive()` right before storing or sampling, so a call that
    ended while it waited never stores a batch nor consumes samples.
    """

    def __init__(self, context: _Context) -> None:
        remaining = context.time_remaining()
        self.deadline = None if remaining is None else time.monotonic() + remaining
        self._ended = threading.Event()

    def end(self) -> None:
        self._ended.set()

    def alive(self, deadline: Optional[float] = None) -> bool:
        """Not cancelled, and before `deadline` (default: the RPC deadline)."""
        if self._ended.is_set():
            return False
        limit = self.deadline if deadline is None else deadline
        return limit is None or time.monotonic() < limit

    def deadline_with(self, timeout_s: float) -> Optional[float]:
        """The earlier of the RPC deadline and `timeout_s` from now (0: no extra limit)."""
        if not timeout_s:
            return self.deadline
        own = time.monotonic() + timeout_s
        return own if self.deadline is None else min(own, self.deadline)


async def wait_for_change(event: asyncio.Event, deadline: Optional[float]) -> bool:
    """Waits until `event` is set, `deadline` passes or RECHECK_S elapse; False once the
    deadline has passed."""
    remaining = None if deadline is None else deadline - time.monotonic()
    if remaining is not None and remaining <= 0:
        return False
    try:
        await asyncio.wait_for(
            event.wait(), RECHECK_S if remaining is None else min(remaining, RECHECK_S)
        )
    except TimeoutError:
        pass
    return True
