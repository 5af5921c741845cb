"""Two agents of one mission play in one world, through graft's client and through the
published ``malmoenv`` client: role 0 (the builder) places dirt on its turn, role 1 (the
breaker) sees it in its grid and the builder among its nearby entities, breaks it on its
turn, and the builder then sees the cell empty again and the breaker near it. The
turns rotate between the roles, and one agent's quit ends the mission for both.

Malmo's rule the replies follow: a step's info shows the world before that step's
commands ran, and an agent's turn comes only once the other agent's turn has run.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from minecraft.malmo.client import MalmoClient
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import IDEAL

SHARED = (Path(__file__).with_name("missions") / "two_agents_shared.xml").read_text()


def _names(info: dict[str, Any]) -> list[str]:
    return [e["name"] for e in info["near"]]


def _seen(info: dict[str, Any], name: str) -> tuple[float, float]:
    (e,) = [e for e in info["near"] if e["name"] == name]
    return e["x"], e["z"]


def _same_world(servers: list[WorldServer]) -> None:
    worlds = [s.inst.world for s in servers]
    assert worlds[0] is not None and worlds[1] is not None
    assert worlds[0] is not worlds[1]  # each agent has its own player, mission and clock
    assert worlds[1].blocks is worlds[0].blocks  # ... on the same blocks


@pytest.fixture
def two_ideal_servers() -> Iterator[list[WorldServer]]:
    """Two world servers with graft's ideal pacing: every step's reply carries the
    observation after its command. Real pacing may answer a step with empty info, and a
    turn-based agent cannot then ask again until the other agent's turn has run (the
    malmoenv test below plays the shared world in real pacing)."""
    servers = [WorldServer(port=0, seed=9, timing=IDEAL) for _ in range(2)]
    for s in servers:
        s.start()
    yield servers
    for s in servers:
        s.stop()


def test_two_graft_clients_build_and_break_in_one_world(
    two_ideal_servers: list[WorldServer], run_together: Callable[..., None]
) -> None:
    two_servers = two_ideal_servers
    head = ("127.0.0.1", two_servers[0].port)
    builder, breaker = (
        MalmoClient("127.0.0.1", s.port, role=k, exp_uid="shared", head=head, timeout=10)
        for k, s in enumerate(two_servers)
    )
    for c in (builder, breaker):
        c.init(SHARED)
    run_together(builder.reset, breaker.reset)
    _same_world(two_servers)

    first = builder.step("use 1")  # the builder's turn: dirt onto the ground ahead
    assert first.sent and first.info["spot"] == ["air"]
    # The breaker's turn comes once the dirt is placed; its info shows the world then.
    seen = breaker.step("attack 1")
    assert seen.sent and seen.info["spot"] == ["dirt"]
    assert _names(seen.info) == ["Breaker", "Builder"]
    assert _seen(seen.info, "Builder") == (0.5, 0.5)
    # The builder's next turn comes once the dirt is broken.
    after = builder.step("turn 1")
    assert after.sent and after.info["spot"] == ["air"]
    assert _seen(after.info, "Breaker") == (0.5, 4.5)
    assert two_servers[0].inst.world.get(0, 4, 2) == 0  # type: ignore[union-attr]

    breaker.quit()  # one agent's quit ends the shared mission for both
    assert builder.observe().done
    for c in (builder, breaker):
        c.close()


def test_two_malmoenv_clients_build_and_break_in_one_world(
    two_servers: list[WorldServer], run_together: Callable[..., None]
) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import malmoenv
    envs = [malmoenv.make() for _ in two_servers]
    for k, (env, s) in enumerate(zip(envs, two_servers, strict=True)):
        env.init(SHARED, two_servers[0].port, port2=s.port, role=k, exp_uid="shared")
    infos: dict[str, dict[str, Any]] = {}

    def turn(k: int, action: str) -> dict[str, Any]:
        # The published client steps with an empty key until a reply gives it one; out
        # of turn Malmo queues such a step and TurnBasedCommands drops it. The step after
        # which the client holds a key took the turn.
        env = envs[k]
        while True:
            _, _, done, info = env.step(env.action_space.actions.index(action))
            assert not done
            if env.turn_key:
                return json.loads(info)

    def build() -> None:
        envs[0].reset()
        infos["built"] = turn(0, "use 1")
        infos["after"] = turn(0, "turn 1")  # once the breaker's turn has run

    def destroy() -> None:
        envs[1].reset()  # finds role 0's mission with <Find>
        infos["seen"] = turn(1, "attack 1")

    run_together(build, destroy)
    _same_world(two_servers)
    assert infos["built"]["spot"] == ["air"]
    assert infos["seen"]["spot"] == ["dirt"] and _seen(infos["seen"], "Builder") == (0.5, 0.5)
    assert infos["after"]["spot"] == ["air"] and _seen(infos["after"], "Breaker") == (0.5, 4.5)
    for env in envs:
        env.close()
