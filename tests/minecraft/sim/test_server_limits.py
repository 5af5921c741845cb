"""What one client may cost a world server, against a real server process: frame and
grid sizes refused at MissionInit before anything is built, messages held only as their
bytes arrive and capped, connections capped and idle ones closed, each refusal an
``error: ...`` message naming the flag. Memory and threads are read from ``/proc``."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from minecraft.malmo import protocol as P
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.limits import DEFAULT_LIMITS
from tests.minecraft.conftest import (
    FLAT,
    connect,
    flat_mission,
    mission_init,
    received_until_closed,
    served,
    status,
)

MIB = 1 << 20


def proc_status(pid: int, key: str) -> int:
    """A number from ``/proc/<pid>/status`` (kB for memory, a count for Threads)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise KeyError(key)


def _wait_for(what: str, ready: Callable[[], bool], timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:.0f} s")
        time.sleep(0.05)


def _reply_then_closed(s: socket.socket) -> str:
    """Everything the server sent before closing ``s``, as framed text."""
    data = received_until_closed(s, 30)
    assert data, "closed without a reply"
    assert P.frame(data[4:]) == data, "more than one message before closing"
    return data[4:].decode()


@pytest.fixture(scope="module")
def default_server() -> Iterator[tuple[int, int]]:
    """(pid, port) of a server process with the default limits."""
    with served() as (proc, [port]):
        yield proc.pid, port


@pytest.mark.service
def test_frames_and_grids_over_the_limits_are_refused_before_anything_is_built(
    default_server: tuple[int, int],
) -> None:
    huge_frame = mission_xml(width=2000, height=2000, flat=FLAT)
    huge_grid = flat_mission(grid_radius=80)  # 161³ cells
    pid, port = default_server
    peak = proc_status(pid, "VmHWM")
    with connect(port) as s:
        ok, reason = mission_init(s, huge_frame)
        assert ok == 0 and "<VideoProducer> 2000x2000" in reason
        assert f"at most {DEFAULT_LIMITS.max_frame_pixels:,} (--max-frame-pixels)" in reason
        ok, reason = mission_init(s, huge_grid, "exp:0:2:1")
        assert ok == 0 and "<ObservationFromGrid> has 4,173,281 cells" in reason
        assert "--max-grid-cells" in reason
        assert mission_init(s, flat_mission(video=True), "exp:0:3:1") == (1, "")
    # Nothing was drawn or built for the refused missions: the peak RSS barely moved
    # (one 2000x2000 frame alone is 12 MB, and drawing it needs many times that).
    assert proc_status(pid, "VmHWM") - peak < 40 * 1024


@pytest.mark.service
def test_a_long_message_is_held_only_as_its_bytes_arrive_and_capped(
    default_server: tuple[int, int],
) -> None:
    cap, n = DEFAULT_LIMITS.max_message_bytes, 16
    pid, port = default_server
    rss = proc_status(pid, "VmRSS")
    # Each announces a message of the largest allowed size and sends one byte of it.
    slow = [connect(port) for _ in range(n)]
    for s in slow:
        s.sendall(cap.to_bytes(4, "big") + b"<")
    _wait_for("the connections are served", lambda: status(port)["connections"] > n)
    status(port)  # one more round trip: every connection's thread is reading by now
    grown = proc_status(pid, "VmRSS") - rss
    assert grown < n * cap // 1024 // 4, f"{grown} kB for {n} announced {cap // MIB} MiB"

    # A message at the cap is served (an Echo of it comes back whole) ...
    with connect(port) as s:
        body = b"<Echo" + b" " * (cap - 5)
        P.send(s, body)
        assert P.recv(s, 2 * cap) == b"<Echo>" + body + b"</Echo>"
    # ... one byte longer is refused, unread, with the limit named.
    with connect(port) as s:
        s.sendall((cap + 1).to_bytes(4, "big"))
        reply = _reply_then_closed(s)
    assert reply == (
        f"error: message of {cap + 1} bytes exceeds the limit of {cap} bytes (--max-message-bytes)"
    )
    for s in slow:
        s.close()


@pytest.mark.service
def test_connections_are_capped_and_idle_ones_closed() -> None:
    cap, opened = 8, 30
    with served("--max-connections", str(cap), "--idle-timeout-s", "1") as (proc, [port]):
        base = proc_status(proc.pid, "Threads")
        peak, stop = [base], threading.Event()

        def watch() -> None:
            while not stop.is_set():
                peak[0] = max(peak[0], proc_status(proc.pid, "Threads"))
                time.sleep(0.005)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            socks = [connect(port) for _ in range(opened)]  # each sends a hello, then nothing
            replies = [_reply_then_closed(s) for s in socks]
        finally:
            stop.set()
            watcher.join()
        full = f"error: the server has {cap} connections open, its limit (--max-connections)"
        idle = "error: idle for 1 s (--idle-timeout-s); closing"
        assert set(replies) == {full, idle}
        assert replies.count(idle) >= cap
        assert peak[0] <= base + cap  # one thread per open connection, never more
        for s in socks:
            s.close()
        # Idle connections do not hold threads: they are all gone, and the server serves.
        _wait_for("the threads end", lambda: proc_status(proc.pid, "Threads") <= base)
        st = status(port)
        assert st["refused_connections"] == replies.count(full)
