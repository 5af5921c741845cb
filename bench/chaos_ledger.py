"""The chaos benchmark's replay harness: a server on a checkpoint folder, writers inserting
numbered unique values, the ledger of what they had acknowledged, and the audit that reads
the folder back whole and counts items lost and doubled.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient
from service.replay.errors import ReplayError

SIGNATURE = {"x": {"dtype": "int64", "shape": []}}
MAX_SIZE = 4_000_000


def free_port() -> int:
    """A loopback port free now, for a server that must come back on the same port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def table(rate_limiter: dict[str, Any], name: str = "t") -> dict[str, Any]:
    return {
        "name": name, "max_size": MAX_SIZE, "sampler": "fifo", "signature": SIGNATURE,
        "rate_limiter": rate_limiter,
    }  # fmt: skip


def server(
    tables: list[dict[str, Any]], folder: Path, *, port: int = 0, extra: tuple[str, ...] = ()
) -> ReplayProcess:
    return ReplayProcess(tables, port=port, extra_args=["--checkpoint-dir", str(folder), *extra])


def audit(folder: Path) -> np.ndarray:
    """Every stored x, read from a fresh server on the folder (no rate limiter in the way)."""
    with server([table({"kind": "min_size", "min_size": 1})], folder) as s:
        client = ReplayClient(s.address, max_message_bytes=1 << 30)
        size = client.info()[0].size
        if size == 0:
            return np.zeros(0, np.int64)
        return client.sample("t", size, timeout=60)["x"]


@dataclass
class Ledger:
    """The batches the writers had acknowledged, and the errors of those they gave up on."""

    acked: list[np.ndarray] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def wait_for_acks(self, more: int, timeout_s: float = 120.0) -> None:
        """Waits until `more` further batches are acknowledged (the writers are back)."""
        with self.lock:
            target = len(self.acked) + more
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.acked) >= target:
                    return
            time.sleep(0.02)
        raise TimeoutError(f"the writers made no progress in {timeout_s} s")

    def verdict(self, stored: np.ndarray) -> dict[str, int]:
        acked = np.concatenate(self.acked) if self.acked else np.zeros(0, np.int64)
        values, counts = np.unique(stored, return_counts=True)
        return {
            "acked items": len(acked),
            "lost": int(np.setdiff1d(acked, values).size),
            "doubled": int((counts - 1).sum()),
            "stored unacked": int(np.setdiff1d(values, acked).size),
            "writer errors": len(self.errors),
        }


def progress(what: str, ledger: Ledger) -> None:
    with ledger.lock:
        acked, errors = sum(len(a) for a in ledger.acked), len(ledger.errors)
    print(f"    {what}: {acked:,} items acknowledged, {errors} writer errors", flush=True)


def run_writers(
    address: str, ledger: Ledger, stop: threading.Event, *, n: int, pause_s: float
) -> list[threading.Thread]:
    """Writers inserting numbered batches of 10 unique values, resending on UNAVAILABLE."""

    def write(i: int) -> None:
        client = ReplayClient(address, writer_id=f"writer-{i}", max_retries=30)
        j = 0
        while not stop.is_set():
            x = np.arange(10, dtype=np.int64) + (i << 40) + j * 10
            j += 1
            try:
                client.insert("t", {"x": x})
                with ledger.lock:
                    ledger.acked.append(x)
            except ReplayError as error:
                with ledger.lock:
                    ledger.errors.append(str(error))
            time.sleep(pause_s)
        client.close()

    threads = [threading.Thread(target=write, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    return threads
