"""Malmo's own MalmoEnv sample missions (``missions/malmo_samples``, copied from Malmo)
under a world server's default limits: every one of the 17 starts and takes a few
steps, every role of a multi-agent one on its own server (the maze, classroom and build
battle generators included). A mission over a limit reaches the published ``malmoenv``
client as an error, not as an endless retry."""

from __future__ import annotations

import re
import threading
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from minecraft.malmo.client import MalmoClient
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.limits import DEFAULT_LIMITS
from minecraft.sim.server import WorldServer
from tests.minecraft.compat.conftest import QUICK

SAMPLES = Path(__file__).with_name("missions") / "malmo_samples"

RUN = sorted(p.name for p in SAMPLES.glob("*.xml"))


@pytest.fixture(scope="module")
def servers() -> Iterator[list[WorldServer]]:
    """Three world servers with the default limits (the samples have up to 3 agents)."""
    started = [WorldServer(port=0, seed=5, timing=QUICK, limits=DEFAULT_LIMITS) for _ in range(3)]
    for s in started:
        s.start()
    yield started
    for s in started:
        s.stop()


def _play(client: MalmoClient, xml: str, steps: int) -> None:
    client.init(xml)
    client.reset()
    for _ in range(steps):
        if client.step("turn 0.1").done:
            break
    client.close()


@pytest.mark.slow  # about 25 s in all, most of it the three-agent mission
@pytest.mark.parametrize("name", RUN)
def test_each_sample_mission_runs_under_the_default_limits(
    servers: list[WorldServer], run_together: Callable[..., None], name: str
) -> None:
    xml = (SAMPLES / name).read_text()
    agents = xml.count("<AgentSection")
    head = ("127.0.0.1", servers[0].port)
    clients = [
        MalmoClient("127.0.0.1", servers[k].port, role=k, exp_uid=name, head=head, timeout=30)
        for k in range(agents)
    ]
    run_together(*(lambda c=c: _play(c, xml, steps=3) for c in clients))
    assert all(s.status()["missions_failed"] == 0 for s in servers)


def test_every_sample_is_run() -> None:
    assert len(RUN) == 17


def test_default_frame_limit_covers_every_sample() -> None:
    biggest = max(int(w) * int(h) for p in SAMPLES.glob("*.xml") for w, h in _sizes(p.read_text()))
    assert biggest == 800 * 600 <= DEFAULT_LIMITS.max_frame_pixels


def _sizes(xml: str) -> list[tuple[str, str]]:
    return re.findall(r"<VideoProducer[^>]*>\s*<Width>(\d+)</Width>\s*<Height>(\d+)</Height>", xml)


def test_malmoenv_raises_on_a_mission_over_a_limit(
    servers: list[WorldServer], monkeypatch: pytest.MonkeyPatch
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import malmoenv
        import malmoenv.comms

    # malmoenv's @retry tries 20 times, 10 s apart, then raises the first error; fewer
    # and quicker here. A 0 would be retried every second for ever instead.
    monkeypatch.setattr(malmoenv.comms, "retry_count", 2)
    monkeypatch.setattr(malmoenv.comms, "retry_timeout", 0.01)
    env = malmoenv.make()
    env.init(mission_xml(width=2000, height=2000), servers[0].port, exp_uid="big")
    raised: list[BaseException] = []

    def reset() -> None:
        try:
            env.reset()
        except Exception as e:  # what a malmoenv user sees
            raised.append(e)

    t = threading.Thread(target=reset, daemon=True)
    t.start()
    t.join(30)
    assert not t.is_alive(), "malmoenv is still retrying the refused mission"
    assert raised
    assert "(--max-frame-pixels)" in servers[0].status()["last_refusal"]
    env.close()
