"""The replay server's memory passes (garbage collection and `malloc_trim`): made after
refused or aborted calls only, a few times, never while none is refused; in a thread
with a short period, and in a server process."""

from __future__ import annotations

import gc
import threading
import time
import urllib.request
import weakref
from collections.abc import Callable, Iterator

import grpc
import pytest

from graft.replay_host.process import ReplayProcess
from service.replay._proto import replay_pb2, replay_pb2_grpc
from service.replay.client import ReplayClient
from service.replay.server.allocator import QUIET_PASSES, TRIM_EVERY_S, FreedMemory
from tests.service.replay.helpers import SCALAR_SIGNATURE, free_port, scalar_batch

TABLE = [
    {"name": "t", "max_size": 100, "signature": SCALAR_SIGNATURE},
    {"name": "empty", "max_size": 10, "signature": SCALAR_SIGNATURE},
]

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


def memory_passes(metrics_port: int) -> int:
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=10) as r:
        text = r.read().decode()
    return int(float(text.split("\ngraft_replay_memory_passes_total ")[1].split()[0]))


@pytest.mark.service
@pytest.mark.serial  # seconds of the server's own pass timer
def test_a_server_makes_passes_after_refused_and_aborted_calls_only() -> None:
    """Ordinary inserts and samples cost no pass; a refused insert and a sample stream
    its client cancels while it waits each get theirs (counted in the metrics)."""
    port = free_port()
    with ReplayProcess(TABLE, extra_args=["--metrics-port", str(port)]) as server:
        client = ReplayClient(server.address)
        for k in range(3):
            client.insert("t", scalar_batch(range(k, k + 4)))
        channel = grpc.insecure_channel(server.address)
        s = replay_pb2_grpc.ReplayServiceStub(channel)
        ask = replay_pb2.SampleRequest(table="t", batch_size=2, num_batches=1)
        for _ in range(3):
            assert len(list(s.Sample(iter([ask])))) == 1
        time.sleep(3 * TRIM_EVERY_S)  # a pass would have come within one period
        assert memory_passes(port) == 0

        with pytest.raises(grpc.RpcError):
            s.Insert(iter([replay_pb2.InsertRequest(table="n" * 2**20)]))
        wait_until(lambda: memory_passes(port) == 1 + QUIET_PASSES)

        empty = replay_pb2.SampleRequest(table="empty", batch_size=1, num_batches=1)
        waiting = s.Sample(iter([empty]))  # waits: the table holds nothing
        time.sleep(0.5)  # the call reaches the server and parks on the rate limiter
        waiting.cancel()
        wait_until(lambda: memory_passes(port) == 2 * (1 + QUIET_PASSES))
        channel.close()
