"""Fixtures: a real world server (in a thread, on a free port) and synchronous clients on
small flat worlds built from mission XML, so each test draws exactly the scene it needs.

The servers pace missions like real Malmo (loading, busy replies, frames at their own
rate, empty info), with delays short enough to keep the tests quick (``FAST``)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Optional

import pytest

from minecraft.malmo import protocol as P
from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.pool import timing_flags
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import Timing

# Real Malmo's behaviour with short delays: 50 ms loading, 20 ms ending, 60 fps.
FAST = Timing(loading_s=0.05, ending_s=0.02, fps=60.0, wait_s=0.5)

# Bedrock, two dirt, grass: the ground's top face is y=4, the agent stands at y=4.
FLAT = "3;7,2*3,2;1;"
GROUND = 4.0


@contextmanager
def served(*flags: str, instances: int = 1) -> Iterator[tuple[subprocess.Popen[bytes], list[int]]]:
    """A ``graft minecraft serve`` process (``FAST`` timing, free ports) and its ports;
    its log goes to a temporary file, quoted when it fails to start."""
    cmd = [
        sys.executable, "-m", "minecraft.cli", "minecraft", "serve", "--port", "0",
        "--instances", str(instances), *timing_flags(FAST), *flags,
    ]  # fmt: skip
    root = str(Path(__file__).resolve().parents[2])
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, cwd=root)
        try:
            assert proc.stdout is not None
            ports = []
            for _ in range(instances):
                line = proc.stdout.readline().decode()
                if not line:
                    log.seek(0)
                    raise RuntimeError(f"{cmd} exited: {log.read().decode()[-2000:]}")
                ports.append(int(line.rsplit(":", 1)[1]))
            yield proc, ports
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def received_until_closed(s: socket.socket, timeout: float) -> bytes:
    """Everything the server sent on ``s`` before it closed it (a reset counts as closed).

    Raises:
        TimeoutError: the connection stayed open for `timeout` seconds of silence.
    """
    s.settimeout(timeout)
    data = b""
    try:
        while chunk := s.recv(4096):
            data += chunk
    except ConnectionResetError:
        pass
    return data


def connect(port: int, timeout: float = 10.0) -> socket.socket:
    """A MalmoEnv connection (hello sent) to a server on loopback."""
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    P.send(s, P.HELLO.encode())
    return s


def status(port: int) -> dict[str, Any]:
    """A server's ``<Status/>``, on a connection of its own."""
    with connect(port) as s:
        P.send(s, b"<Status/>")
        return dict(json.loads(P.recv(s)))


def init_reply(s: socket.socket, *, minerl: bool = False) -> tuple[int, str]:
    """A MissionInit's reply: (ok, the turn key), or (0, ``error: ...``) for a mission
    the server will never run (one message in place of the ok int)."""
    first = P.recv(s)
    if first.startswith(b"error: "):
        return 0, first.decode()
    return P.unpack_int(first), "" if minerl else P.recv(s).decode()


def mission_init(s: socket.socket, xml: str, token: str = "exp:0:1:1") -> tuple[int, str]:
    """MissionInit on ``s``: (ok, the turn key or the refusal's ``error: ...``)."""
    P.send(s, P.mission_init_xml(xml, "exp").encode(), token.encode())
    return init_reply(s, minerl=len(token.split(":")) > 4)


@pytest.fixture
def server() -> Iterator[WorldServer]:
    """A world server on a free port (ticks every 20 ms by default), real timing."""
    with WorldServer(port=0, seed=7, ms_per_tick=20, timing=FAST) as s:
        yield s


def flat_mission(
    *,
    decorators: str = "",
    inventory: tuple[tuple[int, str, int], ...] = (),
    rewards: str = "",
    placement: tuple[float, float, float] = (0.5, GROUND, 0.5),
    video: bool = False,
    ms_per_tick: int = 20,
    grid_radius: int = 2,
    time_limit_ms: Optional[int] = None,
) -> str:
    """A flat-world mission with every handler and the agent at (0.5, 4, 0.5) facing +z;
    a 16×12 frame with ``video``, else the small frame of an agent without pixels."""
    return mission_xml(
        width=16 if video else None,
        height=12 if video else None,
        ms_per_tick=ms_per_tick,
        time_limit_ms=time_limit_ms,
        flat=FLAT,
        grid_radius=grid_radius,
        placement=placement,
        inventory=inventory,
        decorators=decorators,
        rewards=rewards,
    )


@pytest.fixture
def sync_client(server: WorldServer) -> Iterator[Callable[..., MalmoClient]]:
    """Factory: a synchronous graft client already reset into ``flat_mission(**kw)``.

    One Minecraft runs one mission: making a client closes the previous one (which
    quits its mission), as a real Malmo would stay busy with it otherwise."""
    made: list[MalmoClient] = []

    def make(**kw: object) -> MalmoClient:
        for old in made:
            old.close()
        c = MalmoClient("127.0.0.1", server.port, synchronous=True, timeout=10)
        c.init(flat_mission(**kw))  # type: ignore[arg-type]
        c.reset()
        made.append(c)
        return c

    yield make
    for c in made:
        c.close()
