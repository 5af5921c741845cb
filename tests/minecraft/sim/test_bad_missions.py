"""Missions that would break the simulator, against a real world-server process: numbers
that are not finite are refused at MissionInit with the attribute named (by graft's
client too, before anything is sent), and a mission the simulator fails on while it runs
ends alone: its agent sees the end, and the server's other missions go on."""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator

import pytest

from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission import MissionError
from tests.minecraft.conftest import connect, flat_mission, mission_init, served, status

BIG = "1" + "0" * 400  # a decimal past a double's range: it reads as infinity
NEAR_MAX = "17" + "0" * 307  # 1.7e308: finite, but turning at this speed overflows the yaw

BASE = flat_mission(
    video=True,
    time_limit_ms=60_000,
    decorators='<DrawEntity x="2" y="4" z="3" type="Pig"/>'
    '<DrawItem x="1" y="4" z="1" type="diamond"/>',
    rewards='<RewardForSendingCommand reward="1"/>',
)


def with_attr(xml: str, tag: str, attr: str, value: str) -> str:
    """``xml`` with ``attr="value"`` on its first ``<tag>`` (set or added)."""
    start = re.search(rf"<{tag}\b[^>]*?(/?)>", xml)
    assert start is not None, tag
    element = start.group(0)
    if re.search(rf'\s{attr}="', element):
        new = re.sub(rf'(\s{attr}=")[^"]*"', rf'\g<1>{value}"', element)
    else:
        new = element.replace(f"<{tag}", f'<{tag} {attr}="{value}"', 1)
    return xml[: start.start()] + new + xml[start.end() :]


def _wait_for(what: str, ready: Callable[[], bool], timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout_s:.0f} s")
        time.sleep(0.05)


@pytest.fixture(scope="module")
def ideal_port() -> Iterator[int]:
    """One server process for the refusals (ideal timing: a mission replaces the last)."""
    with served("--ideal") as (_, [port]):
        yield port


@pytest.mark.parametrize(
    ("tag", "attr", "value"),
    [
        ("DrawEntity", "x", BIG),
        ("DrawEntity", "x", "nan"),
        ("DrawEntity", "yaw", BIG),
        ("DrawItem", "x", "inf"),
        ("Placement", "x", BIG),
        ("Placement", "yaw", "NaN"),
        ("ContinuousMovementCommands", "turnSpeedDegs", BIG),
        ("ServerQuitFromTimeUp", "timeLimitMs", BIG),
        ("Range", "xrange", BIG),
        ("RewardForSendingCommand", "reward", BIG),
    ],
)
@pytest.mark.service
def test_numbers_that_are_not_finite_are_refused_naming_the_attribute(
    ideal_port: int, tag: str, attr: str, value: str
) -> None:
    xml = with_attr(BASE, tag, attr, value)
    with pytest.raises(MissionError, match=rf"<{tag}>.*{attr}="):
        MalmoClient().init(xml)  # graft's own check, before any traffic
    with connect(ideal_port) as s:
        ok, reason = mission_init(s, xml)
        assert ok == 0
        assert reason.startswith("error: ") and f"<{tag}>" in reason and f"{attr}=" in reason
        # The same connection and server go on: a valid mission starts.
        assert mission_init(s, BASE) == (1, "")


@pytest.mark.parametrize("synchronous", [False, True], ids=["malmo", "minerl"])
@pytest.mark.service
def test_a_mission_the_simulator_fails_on_ends_alone_and_the_server_goes_on(
    synchronous: bool,
) -> None:
    # Malmo accumulates yaw without wrapping it: at 1.7e308 degrees/s the yaw passes a
    # double's range within a few ticks of turning, and the simulator's trigonometry
    # raises. That one mission must end; the instance runs its next mission and the
    # other instance goes on.
    turning = with_attr(BASE, "ContinuousMovementCommands", "turnSpeedDegs", NEAR_MAX)
    with served(instances=2) as (_, [port, other_port]):
        other = MalmoClient("127.0.0.1", other_port, timeout=10)
        other.init(BASE)
        other.reset()
        bad = MalmoClient("127.0.0.1", port, timeout=10, synchronous=synchronous)
        bad.init(turning)
        bad.reset()
        for _ in range(500):
            r = bad.step("turn 1")
            if r.done:
                break
        assert r.done
        st = status(port)
        assert st["end_reason"].startswith("error: the simulator failed: ValueError")
        assert st["missions_failed"] == 1

        tick = status(other_port)["tick"]
        _wait_for("the other instance's mission ticks", lambda: status(other_port)["tick"] > tick)
        assert not other.step("move 1").done

        good = MalmoClient("127.0.0.1", port, timeout=10)
        good.init(BASE)
        good.reset()  # the failed mission's instance takes a new mission
        good.step("move 1")
        _wait_for("the next mission ticks", lambda: status(port)["tick"] > 5)
        assert status(port)["missions_started"] == 2
        for c in (bad, good, other):
            c.close()
