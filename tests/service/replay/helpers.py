"""Helpers shared by the replay-server tests: tables, free ports, reading a table whole."""

from __future__ import annotations

import socket
import subprocess
from pathlib import Path

import numpy as np

from service.replay.client import ReplayClient

SCALAR_SIGNATURE = {
    "x": {"dtype": "int64", "shape": []},
    "terminated": {"dtype": "bool", "shape": []},
    "truncated": {"dtype": "bool", "shape": []},
}


def scalar_batch(values, *, ends=None) -> dict[str, np.ndarray]:
    x = np.asarray(values, dtype=np.int64)
    ends = np.zeros(len(x), bool) if ends is None else np.asarray(ends, bool)
    return {"x": x, "terminated": ends, "truncated": np.zeros(len(x), bool)}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def read_all(client: ReplayClient, table: str) -> np.ndarray:
    """Every stored `x`, oldest first (the table must use the fifo sampler)."""
    size = next(t.size for t in client.info() if t.name == table)
    if size == 0:
        return np.zeros(0, np.int64)
    return client.sample(table, size, timeout=5)["x"]


def self_signed_cert(folder: Path) -> tuple[Path, Path]:
    """A throwaway certificate for localhost and 127.0.0.1: (cert.pem, key.pem) in `folder`."""
    cert, key = folder / "cert.pem", folder / "key.pem"
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1",
         "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
         "-keyout", str(key), "-out", str(cert)],
        check=True, capture_output=True,
    )  # fmt: skip
    return cert, key
