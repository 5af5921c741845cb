"""A multi-agent mission whose other roles never join ends, and frees its world server,
within a bounded time: at once when role 0's connection closes while it waits for them,
and after ``Timing.join_s`` (``--join-s``; Malmo's 2,000 client ticks, 100 s) while
role 0 stays. Against a real server on loopback."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from minecraft.malmo import protocol as P
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import REAL
from tests.minecraft.conftest import FAST, connect, flat_mission, mission_init

# Join timeouts and abandoned missions wait in real time.
pytestmark = pytest.mark.serial

TWO_AGENTS = (
    Path(__file__).parents[1] / "compat" / "missions" / "two_agents_shared.xml"
).read_text()


@pytest.fixture
def server() -> Iterator[WorldServer]:
    """A world server whose multi-agent missions wait 1 s for the other roles."""
    with WorldServer(port=0, timing=dataclasses.replace(FAST, join_s=1.0)) as s:
        yield s


def _free_again(server: WorldServer, timeout_s: float) -> float:
    """Seconds until a single-agent MissionInit is accepted; fails after ``timeout_s``
    (the server used to answer busy until ``<Exit>``)."""
    t0 = time.monotonic()
    with connect(server.port) as s:
        for reset in range(1, 10_000):
            ok, _ = mission_init(s, flat_mission(), f"solo:0:{reset}:1")
            if ok == 1:
                return time.monotonic() - t0
            assert time.monotonic() - t0 < timeout_s, f"still busy: {server.status()}"
            time.sleep(0.02)
    raise AssertionError("unreachable")


def test_the_join_timeout_is_malmos_by_default() -> None:
    assert REAL.join_s == 100.0  # 2,000 client ticks of 50 ms


def test_role_0_leaving_before_the_others_join_ends_the_mission_at_once(
    server: WorldServer,
) -> None:
    server.timing = server.inst.timing = dataclasses.replace(FAST, join_s=60.0)
    with connect(server.port) as s:
        ok, _ = mission_init(s, TWO_AGENTS, "x:0:1:2")
        assert ok == 1
        assert server.status()["phase"] == "loading"
    # Role 0's connection closed while it waited for role 1: nobody will play it.
    assert _free_again(server, timeout_s=5.0) < 5.0
    assert server.status()["missions_started"] == 2


def test_a_mission_the_others_never_join_ends_after_the_join_timeout(
    server: WorldServer,
) -> None:
    with connect(server.port) as s:
        ok, _ = mission_init(s, TWO_AGENTS, "x:0:1:2")
        assert ok == 1
        t0 = time.monotonic()
        while server.status()["phase"] == "loading":
            assert time.monotonic() - t0 < 10.0, "still waiting for role 1"
            time.sleep(0.02)
        st = server.status()
        assert st["phase"] == "ended"
        assert "did not join within 1 s (--join-s)" in str(st["end_reason"])
        P.send(s, b"<Peek/>")  # role 0, still connected, is told the mission is over
        P.recv(s)
        assert P.recv(s) == b"\x01"
        # ... and role 1, coming late, finds no mission to join.
        P.send(s, b"<Find>x:1:1</Find>")
        assert P.unpack_int(P.recv(s)) == 0
    assert _free_again(server, timeout_s=5.0) < 5.0
