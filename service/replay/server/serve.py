"""The replay server process: serves until SIGTERM/SIGINT (or its parent's death), with
periodic checkpoints, then health NOT_SERVING, a final checkpoint and a graceful stop."""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
from contextlib import suppress
from typing import Optional

from service.replay.server.durability import StorageError
from service.replay.server.grpc_server import ServerOptions, build_server, host_port
from service.replay.server.store import ReplayCore

log = logging.getLogger(__name__)


def _stop_when_orphaned(parent_pid: int, stop: threading.Event, poll_s: float = 1.0) -> None:
    """Sets `stop` once we are no longer `parent_pid`'s child (it died: we were re-parented).

    A launcher killed with SIGKILL cannot stop its replay server; without this the server
    would outlive it and keep its port and memory.
    """
    while not stop.wait(poll_s):
        if os.getppid() != parent_pid:
            log.warning("parent process %d is gone; stopping", parent_pid)
            stop.set()


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
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
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
    threading.Thread(target=running.freed_memory.run, args=(stop,), daemon=True).start()
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
