"""The replay server process: serves until SIGTERM/SIGINT (or its parent's death), with
periodic checkpoints, then health NOT_SERVING, a final checkpoint and a graceful stop."""

from __future__ import annotations

import json
import logging
import os
import select
import signal
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from typing import Optional

from service.replay.server.durability import StorageError
from service.replay.server.grpc_server import ServerOptions, build_server, host_port
from service.replay.server.store import ReplayCore

log = logging.getLogger(__name__)


class _StopRequest:
    """A stop that a signal or any thread may ask for, and that the main thread's wait sees
    at once.

    Python runs signal handlers on the main thread only, and a signal the kernel hands to
    another thread (gRPC's, ours) does not wake a main thread blocked in `Event.wait`: it
    slept on until its next checkpoint (300 s by default), and a supervisor's SIGTERM
    ended in SIGKILL, without the final checkpoint. Here the main thread waits on a pipe
    that Python's C-level handler writes to (`signal.set_wakeup_fd`), whichever thread
    took the signal.
    """

    def __init__(self) -> None:
        self.event = threading.Event()
        """Set once a stop is asked for (what the other threads wait on)."""
        self._read, self._write = os.pipe()
        os.set_blocking(self._write, False)

    def on_signals(self, *signals: int) -> None:
        """Asks for the stop on each of `signals` (from the main thread)."""
        signal.set_wakeup_fd(self._write)
        for sig in signals:
            signal.signal(sig, lambda *_: self.set())

    def set(self) -> None:
        self.event.set()
        with suppress(BlockingIOError):  # a full pipe already wakes the waiter
            os.write(self._write, b"\0")

    def wait(self, timeout: Optional[float]) -> bool:
        """Waits at most `timeout` seconds (None: for ever) for the stop; True if asked.

        A byte may come before the Python handler has run (it runs on the main thread's
        next instructions, and writes a byte of its own): the wait goes on until the stop
        is set or the time is up."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self.event.is_set():
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                return False
            if select.select([self._read], [], [], left)[0]:
                os.read(self._read, 4096)
        return True


def _stop_when_orphaned(parent_pid: int, stop: _StopRequest, poll_s: float = 1.0) -> None:
    """Asks for the stop once process `parent_pid`, the one that started us (our parent,
    or the parent of the fork server we were forked from), has died.

    A launcher killed with SIGKILL cannot stop its replay server; without this the server
    would outlive it and keep its port and memory.
    """
    gone = _death_check(parent_pid)
    while not stop.event.wait(poll_s):
        if gone():
            log.warning("parent process %d is gone; stopping", parent_pid)
            stop.set()


def _death_check(pid: int) -> Callable[[], bool]:
    """A check, True once process `pid` has died: its pidfd (Linux) says so; without
    pidfds (another system, a container's seccomp), we have been re-parented if `pid` is
    our parent, else no process has its pid any more."""
    try:
        pidfd = os.pidfd_open(pid)
    except ProcessLookupError:
        return lambda: True
    except (AttributeError, OSError):
        if os.getppid() == pid:
            return lambda: os.getppid() != pid
        return lambda: not _exists(pid)
    return lambda: bool(select.select([pidfd], [], [], 0)[0])


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's: it exists
        pass
    return True


def serve_forever(
    core: ReplayCore,
    options: ServerOptions,
    *,
    ready_file: Optional[str] = None,
    metrics_port: Optional[int] = None,
    metrics_host: str = "127.0.0.1",
    checkpoint_every_s: float = 0.0,
    grace_s: float = 5.0,
    parent_pid: Optional[int] = None,
) -> None:
    """Runs until SIGTERM/SIGINT (or, with `parent_pid`, until that parent has died), then:
    health NOT_SERVING, final checkpoint, graceful stop.

    The metrics endpoint answers without a token, so it binds `metrics_host` (loopback
    unless told otherwise), whatever `options.host` is. A failed checkpoint is logged and
    counted, and the next period tries again; the log keeps every insert meanwhile."""
    # Before the server answers or says it is ready: a stop sent the moment it is ready
    # (a test's, a supervisor's) must still get the final checkpoint, not Python's default
    # SIGTERM, which ends the process on the spot.
    stop = _StopRequest()
    stop.on_signals(signal.SIGTERM, signal.SIGINT)
    running = build_server(core, options, metrics=metrics_port is not None)
    address = host_port(options.host, running.port)
    extra = ""
    if running.metrics is not None and metrics_port is not None:
        bound = running.metrics.serve(metrics_port, metrics_host.strip("[]"))
        extra = f", metrics on http://{host_port(metrics_host, bound)}/metrics"
    print(f"replay server listening on {address}{extra}", flush=True)
    log.info("tables: %s", sorted(core.tables))
    if ready_file:
        with open(ready_file + ".tmp", "w") as f:
            json.dump({"address": address}, f)
        os.replace(ready_file + ".tmp", ready_file)  # atomic: readers never see half a file
    # Refused megabyte requests would otherwise leave RSS tens of MiB up (cyclic garbage,
    # and free pages glibc's malloc keeps).
    threading.Thread(target=running.freed_memory.run, args=(stop.event,), daemon=True).start()
    if parent_pid is not None:
        threading.Thread(target=_stop_when_orphaned, args=(parent_pid, stop), daemon=True).start()
    while not stop.wait(checkpoint_every_s or None):
        with suppress(StorageError):  # logged and counted by the core
            core.checkpoint()  # periodic; sampling goes on while the file is written
    running.health.enter_graceful_shutdown()
    with suppress(StorageError):
        core.checkpoint()
    running.server.stop(grace_s).wait()
    core.close()
