"""A bounded thread pool that gives each job to the most recently idle thread.

Python's ThreadPoolExecutor wakes its idle threads in turn, so the jobs of one sample
stream rotate over every thread the pool has ever started. Each thread allocates from
its own malloc arena, and batches of megabytes then come from cold memory every time:
after a burst of 16 concurrent writers, sampling large batches ran at half speed. Reusing
the hottest thread keeps sequential work on one thread, as a thread-per-call server did.
"""

from __future__ import annotations

import functools
import queue
import threading
from collections import deque
from collections.abc import Callable
from concurrent import futures
from typing import Any, Optional, TypeVar

T = TypeVar("T")
_Job = tuple[futures.Future[Any], Callable[[], Any]]


class HotThreadPool(futures.Executor):
    """At most `max_workers` threads, started on demand; idle threads are reused last-in
    first-out, and jobs beyond `max_workers` wait in order."""

    def __init__(self, max_workers: int, *, thread_name_prefix: str = "pool") -> None:
        if max_workers < 1:
            raise ValueError(f"max_workers must be >= 1, got {max_workers}")
        self._max_workers = max_workers
        self._prefix = thread_name_prefix
        self._lock = threading.Lock()
        self._idle: list[queue.SimpleQueue[Optional[_Job]]] = []  # a stack: last idle on top
        self._backlog: deque[_Job] = deque()
        self._threads: list[threading.Thread] = []
        self._shutdown = False

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> futures.Future[T]:
        future: futures.Future[T] = futures.Future()
        job: _Job = (future, functools.partial(fn, *args, **kwargs))
        with self._lock:
            if self._shutdown:
                raise RuntimeError("cannot schedule new jobs after shutdown")
            if self._idle:
                self._idle.pop().put(job)
            elif len(self._threads) < self._max_workers:
                thread = threading.Thread(
                    target=self._work,
                    args=(job,),
                    name=f"{self._prefix}_{len(self._threads)}",
                    daemon=True,
                )
                self._threads.append(thread)
                thread.start()
            else:
                self._backlog.append(job)
        return future

    def _work(self, job: Optional[_Job]) -> None:
        inbox: queue.SimpleQueue[Optional[_Job]] = queue.SimpleQueue()
        while job is not None:
            future, call = job
            if future.set_running_or_notify_cancel():
                try:
                    future.set_result(call())
                except BaseException as error:  # handed to whoever awaits the future
                    future.set_exception(error)
            del future, call
            job = None  # an idle thread holds no result
            with self._lock:
                if self._backlog:
                    job = self._backlog.popleft()
                    continue
                if self._shutdown:
                    return
                self._idle.append(inbox)
            job = inbox.get()

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """Runs the jobs already submitted (unless `cancel_futures`), then ends the threads."""
        with self._lock:
            self._shutdown = True
            if cancel_futures:
                for future, _ in self._backlog:
                    future.cancel()
                self._backlog.clear()
            for inbox in self._idle:
                inbox.put(None)
            self._idle.clear()
            threads = list(self._threads)
        if wait:
            for thread in threads:
                thread.join()
