"""Fixtures for multi-agent missions: two simulated Minecrafts (real timing, short
delays) and a runner that plays each agent in its own thread."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator

import pytest

from minecraft.sim.server import WorldServer
from minecraft.sim.timing import Timing

QUICK = Timing(loading_s=0.05, ending_s=0.05, fps=60.0, wait_s=0.3)


@pytest.fixture
def two_servers() -> Iterator[list[WorldServer]]:
    """Two world servers on free ports, one per agent, as Malmo's samples run them."""
    servers = [WorldServer(port=0, seed=9, timing=QUICK) for _ in range(2)]
    for s in servers:
        s.start()
    yield servers
    for s in servers:
        s.stop()


def _run_together(*fns: Callable[[], None]) -> None:
    errors: list[BaseException] = []

    def run(fn: Callable[[], None]) -> None:
        try:
            fn()
        except BaseException as e:  # reported below, with the thread's traceback
            errors.append(e)

    threads = [threading.Thread(target=run, args=(f,), daemon=True) for f in fns]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert not any(t.is_alive() for t in threads), "an agent is still waiting for its turn"
    if errors:
        raise errors[0]


@pytest.fixture
def run_together() -> Callable[..., None]:
    """Run each function (one agent's play) in its own thread; re-raise the first
    failure; fail if one is still waiting after 2 minutes."""
    return _run_together
