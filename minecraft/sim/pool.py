"""A pool of world servers on consecutive ports, one subprocess each, like a rack of real
Malmo clients started with ``launchClient.sh -port P -env``.

    with ServerPool(4, base_port=9000, seed=1) as pool:
        ports = pool.ports          # [9000, 9001, 9002, 9003]
"""

from __future__ import annotations

import os
import random
import socket
import subprocess
import time
from pathlib import Path
from typing import Optional

from minecraft.malmo import protocol as P
from minecraft.sim.timing import REAL, Timing
from service import forkserver

_ROOT = str(Path(__file__).resolve().parents[3])


def port_is_free(host: str, port: int) -> bool:
    """Whether ``port`` can be bound on ``host`` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def free_port_block(n: int, host: str = "127.0.0.1", start: Optional[int] = None) -> int:
    """The first port ``p >= start`` such that ``p .. p+n-1`` are all free. Without
    `start`, the search begins at a random port in 20000-39999, so that pools started at
    the same moment by different processes seldom reach for the same block."""
    p = random.randrange(20000, 40000) if start is None else start
    while p + n < 65535:
        bad = next((q for q in range(p, p + n) if not port_is_free(host, q)), None)
        if bad is None:
            return p
        p = bad + 1
    raise RuntimeError(f"no block of {n} free consecutive ports on {host}")


def wait_ready(host: str, port: int, timeout: float = 30.0) -> None:
    """Block until a server answers ``<Status/>`` on ``port``.

    Raises:
        TimeoutError: it did not within ``timeout`` seconds.
    """
    deadline = time.monotonic() + timeout
    last: Optional[Exception] = None
    while time.monotonic() < deadline:
        try:
            with socket.create_connection((host, port), timeout=2.0) as s:
                P.send(s, P.HELLO.encode())
                P.send(s, b"<Status/>")
                P.recv(s)
                return
        except (OSError, ConnectionError) as e:
            last = e
            time.sleep(0.05)
    raise TimeoutError(f"world server {host}:{port} not ready after {timeout}s: {last}")


def timing_flags(timing: Timing) -> list[str]:
    """The ``minecraft serve`` flags that give a server ``timing``."""
    if timing.ideal:
        return ["--ideal", "--join-s", str(timing.join_s)]
    return [
        "--loading-s", str(timing.loading_s), "--ending-s", str(timing.ending_s),
        "--fps", str(timing.fps), "--wait-s", str(timing.wait_s),
        "--join-s", str(timing.join_s),
    ]  # fmt: skip


class ServerPool:
    """Start ``n`` world servers in subprocesses on consecutive ports.

    Args:
        n: number of servers.
        base_port: first port; 0 finds a free block of ``n`` consecutive ports.
        seed: base seed; server i uses ``seed + i`` so the worlds differ.
        ms_per_tick: default tick period of each server.
        host: interface to bind.
        timing: real Malmo's pacing (the default) or ``Timing(ideal=True)``.
    """

    def __init__(
        self, n: int, base_port: int = P.DEFAULT_PORT, *, seed: int = 0, ms_per_tick: int = 50,
        host: str = "127.0.0.1", timing: Timing = REAL,
    ) -> None:  # fmt: skip
        if n < 1:
            raise ValueError(f"a pool needs at least one server, got n={n}")
        self.n, self.seed, self.ms_per_tick, self.host = n, seed, ms_per_tick, host
        self.timing = timing
        self.base_port = base_port
        self.ports: list[int] = []
        self.procs: list[forkserver.Process] = []

    def start(self, timeout: float = 60.0) -> list[int]:
        """Launch the servers and wait until each accepts connections; returns the ports."""
        base = self.base_port or free_port_block(self.n, self.host)
        self.ports = list(range(base, base + self.n))
        env = dict(os.environ)
        # The servers import this package wherever the caller's cwd is.
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [_ROOT, env.get("PYTHONPATH")]))
        env.setdefault("OPENBLAS_NUM_THREADS", "1")  # no linear algebra: no BLAS pool
        for i, port in enumerate(self.ports):
            argv = [
                "minecraft", "serve", "--port", str(port), "--seed", str(self.seed + i),
                "--ms-per-tick", str(self.ms_per_tick), "--host", self.host,
                *timing_flags(self.timing),
            ]  # fmt: skip
            # Forks of a fork server with the simulator and its kernels loaded: a server
            # starts in a few hundredths of a second of CPU, not 0.5 s and 0.5 s more at
            # its first frame.
            server = forkserver.start("minecraft.cli", argv, env=env, own_stderr=True)
            self.procs.append(server)
        try:
            for port, proc in zip(self.ports, self.procs, strict=True):
                if proc.poll() is not None:
                    raise RuntimeError(f"world server on port {port} exited with {proc.returncode}")
                wait_ready(self.host, port, timeout)
        except BaseException:
            self.stop()
            raise
        return self.ports

    def stop(self, grace: float = 5.0) -> None:
        """Terminate the servers (kill those that do not exit within ``grace`` seconds)."""
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(grace)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.procs = []

    def __enter__(self) -> ServerPool:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
