"""Faults the chaos benchmark inflicts on a replay server while writers insert: SIGKILL and
restart cycles (checkpoints on), and connections cut by a resetting proxy while inserts wait
on a rate limiter. Each returns the ledger's verdict on the audited table.
"""

from __future__ import annotations

import random
import socket
import struct
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from chaos_ledger import Ledger, audit, free_port, progress, run_writers, server, table
from procfs import rss_mib

from service.replay.client import ReplayClient
from service.replay.errors import ReplayError

# ------------------------------------------------------------------- 1. SIGKILL


def kill_restart(cycles: int) -> dict[str, Any]:
    """`cycles` SIGKILLs of a server checkpointing every second under 4 writers, each
    followed by a restart on its folder; the ledger's verdict on the audited table."""
    with tempfile.TemporaryDirectory(prefix="chaos-kill-") as tmp:
        folder, port = Path(tmp), free_port()
        limiter = {"kind": "min_size", "min_size": 1}
        extra = ("--checkpoint-every-s", "1")
        current = server([table(limiter)], folder, port=port, extra=extra)
        ledger, stop = Ledger(), threading.Event()
        writers = run_writers(current.address, ledger, stop, n=4, pause_s=0.005)
        for cycle in range(cycles):
            # Each cycle kills a server the writers are busy with: they reconnected and
            # wrote again since the last restart.
            ledger.wait_for_acks(4)
            time.sleep(random.uniform(0.3, 1.2))
            current.kill()
            current.stop()
            current = server([table(limiter)], folder, port=port, extra=extra)
            progress(f"kill {cycle + 1}/{cycles}", ledger)
        time.sleep(0.5)
        stop.set()
        for w in writers:
            w.join(120)
        current.stop()
        return {"cycles": cycles, **ledger.verdict(audit(folder))}


# --------------------------------------------------------- 2. dropped connections


class CuttingProxy:
    """A loopback TCP proxy whose connections can all be cut at once (reset)."""

    def __init__(self, target_port: int) -> None:
        self._target = ("127.0.0.1", target_port)
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = int(self._listener.getsockname()[1])
        self._sockets: set[socket.socket] = set()
        self._lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                downstream, _ = self._listener.accept()
                upstream = socket.create_connection(self._target)
            except OSError:
                return
            with self._lock:
                self._sockets |= {downstream, upstream}
            for src, dst in ((downstream, upstream), (upstream, downstream)):
                threading.Thread(target=self._pump, args=(src, dst), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(1 << 16):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            self._cut([src, dst])

    def _cut(self, sockets: list[socket.socket]) -> None:
        for s in sockets:
            with self._lock:
                self._sockets.discard(s)
            try:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()

    def cut_all(self) -> int:
        with self._lock:
            sockets = list(self._sockets)
        self._cut(sockets)
        return len(sockets) // 2

    def close(self) -> None:
        self._listener.close()
        self.cut_all()


def dropped_connections(cycles: int) -> dict[str, Any]:
    """Writers go through the proxy; a sampler, direct, admits about 10 batches/s through a
    tight sample-to-insert ratio, so inserts wait on the limiter for about 0.4 s each and a
    writer's resend after a cut arrives while its first attempt still waits."""
    with tempfile.TemporaryDirectory(prefix="chaos-drop-") as tmp:
        folder = Path(tmp)
        limiter = {
            "kind": "sample_to_insert_ratio", "samples_per_insert": 1.0, "min_size": 10,
            "error_buffer": 20.0,
        }  # fmt: skip
        s = server([table(limiter)], folder)
        rss_start = rss_mib(s.process.pid)
        proxy = CuttingProxy(int(s.address.rsplit(":", 1)[1]))
        ledger, stop, sampling = Ledger(), threading.Event(), threading.Event()

        def sample() -> None:
            client = ReplayClient(s.address)
            while not sampling.is_set():
                try:
                    client.sample("t", 10, timeout=1.0)
                except ReplayError:
                    pass
                time.sleep(0.1)

        sampler = threading.Thread(target=sample, daemon=True)
        sampler.start()
        writers = run_writers(f"127.0.0.1:{proxy.port}", ledger, stop, n=4, pause_s=0.0)
        cut = 0
        for cycle in range(cycles):
            ledger.wait_for_acks(1)
            time.sleep(random.uniform(0.3, 0.8))
            cut += proxy.cut_all()
            progress(f"cut {cycle + 1}/{cycles}", ledger)
        time.sleep(1.0)
        stop.set()
        for w in writers:
            w.join(120)
        sampling.set()
        sampler.join(30)
        proxy.close()
        rss_end = rss_mib(s.process.pid)
        s.stop()
        verdict = ledger.verdict(audit(folder))
        return {"cycles": cycles, "connections cut": cut, **verdict,
                "rss": (rss_start, rss_end)}  # fmt: skip
