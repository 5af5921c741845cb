"""The replay server's memory passes (garbage collection and `malloc_trim`): made after
refused or aborted calls only, a few times, never while none is refused."""

from __future__ import annotations

import gc
import threading
import time
import weakref
from collections.abc import Callable, Iterator

import pytest

from service.replay.server.allocator import FreedMemory

PERIOD_S = 0.01


def wait_until(condition: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(PERIOD_S / 2)


@pytest.fixture
def freed() -> Iterator[FreedMemory]:
    """A FreedMemory making its passes every 10 ms on a thread of its own."""
    memory = FreedMemory(every_s=PERIOD_S, quiet_passes=2)
    stop = threading.Event()
    thread = threading.Thread(target=memory.run, args=(stop,))
    thread.start()
    yield memory
    stop.set()
    thread.join()
    gc.unfreeze()  # `run` froze this test process's objects


def test_no_pass_while_no_call_is_refused(freed: FreedMemory) -> None:
    time.sleep(30 * PERIOD_S)
    assert freed.passes == 0


def test_a_refused_call_gets_a_pass_and_then_the_quiet_ones(freed: FreedMemory) -> None:
    freed.call_ended_badly()
    wait_until(lambda: freed.passes == 3)  # the one after the call, then 2 without one
    time.sleep(30 * PERIOD_S)
    assert freed.passes == 3
    for _ in range(5):  # calls ended within one period: one pass each period
        freed.call_ended_badly()
    wait_until(lambda: freed.passes == 6)
    time.sleep(30 * PERIOD_S)
    assert freed.passes == 6


def test_a_pass_frees_a_refused_requests_reference_cycle(freed: FreedMemory) -> None:
    class Request:
        """A megabyte request held in a cycle, as a refused stream's last one can be."""

        def __init__(self) -> None:
            self.payload = bytearray(2**20)
            self.me = self

    wait_until(lambda: gc.get_freeze_count() > 0)  # made after the freeze: a pass sees it
    collected = threading.Event()
    gc.disable()  # only the passes collect
    try:
        request = Request()
        weakref.finalize(request, collected.set)
        del request
        assert not collected.wait(30 * PERIOD_S)  # no pass while no call is refused...
        freed.call_ended_badly()
        assert collected.wait(10.0)  # ...and the pass after one frees it
    finally:
        gc.enable()
