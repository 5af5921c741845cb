"""Malmo-style missions (``missions/*.xml``, written for graft after the kinds of missions
Malmo's MalmoEnv samples are) either load and run in the simulator, as in a real
Minecraft (generated buildings and mazes included), or are refused at MissionInit with a
reason naming what is not implemented.

Each runs through a real world server and graft's client."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from minecraft.malmo import protocol as P
from minecraft.malmo.client import MalmoClient, StepResult
from minecraft.sim.server import WorldServer

MISSIONS = Path(__file__).with_name("missions")


@pytest.fixture
def run(server: WorldServer) -> Iterator:
    clients: list[MalmoClient] = []

    def start(name: str) -> MalmoClient:
        c = MalmoClient("127.0.0.1", server.port, synchronous=True, timeout=10)
        clients.append(c)
        c.init((MISSIONS / name).read_text())
        c.reset()
        return c

    yield start
    for c in clients:
        c.close()


def _steps(c: MalmoClient, command: str, n: int) -> tuple[StepResult, float]:
    total = 0.0
    r = c.step(command)
    total += r.reward
    for _ in range(n - 1):
        if r.done:
            break
        r = c.step(command)
        total += r.reward
    return r, total


def test_generated_buildings_and_mazes_load_and_step(run) -> None:
    # The classroom moves the agent from its XML placement (x=-150.5) into the
    # building at (0, 55, 0); the maze onto its start block (standing at y=228).
    school = run("school.xml")
    r, _ = _steps(school, "move 0", 2)
    assert not r.done and 0 < r.info["XPos"] < 9 and 55 <= r.info["YPos"] <= 56
    assert 0 < r.info["ZPos"] < 1
    school.close()  # one Minecraft runs one mission at a time
    r, _ = _steps(run("labyrinth.xml"), "move 0", 2)
    assert not r.done


def test_schema_invalid_missions_are_refused_at_mission_init(server: WorldServer) -> None:
    good = (MISSIONS / "lava_bridge.xml").read_text()
    cases = [
        (P.mission_init_xml(good.replace("<ObservationFromFullStats/>", "<ObservationFromStats/>"),
                            "exp"), "unknown element <ObservationFromStats>"),
        (P.mission_init_xml(good, "exp").replace('PlatformVersion="0.37.0"',
                                                 'PlatformVersion="0.30.0"'),
         "version mismatch: got 0.30.0, expected 0.37.0"),
        (P.mission_init_xml(good.replace('type="lapis_block"/>\n', 'type="lapis"/>\n', 1),
                            "exp"), "'lapis' is not a Minecraft block type"),
    ]  # fmt: skip
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
        P.send(s, P.HELLO.encode())
        for wire, reason in cases:
            P.send(s, wire.encode(), b"exp:0:1:1")
            why = P.recv(s).decode()  # one error message in place of the ok int
            assert why.startswith("error: ") and reason in why, why
        P.send(s, P.mission_init_xml(good, "exp").encode(), b"exp:0:1:1")
        assert P.unpack_int(P.recv(s)) == 1  # the same connection, still serving
        P.recv(s)


def test_an_agent_placed_on_a_227_layer_world_stands_on_it(run) -> None:
    c = run("sky_platform.xml")
    r, _ = _steps(c, "", 40)
    assert (r.info["YPos"], r.info["Life"]) == (227.0, 20.0)
    r, total = _steps(c, "quit", 2)  # the quit's description pays RewardForMissionEnd
    assert r.done and total == -3.0


def test_walking_into_the_hut_reaches_the_marker(run) -> None:
    c = run("sky_platform.xml")
    r, total = _steps(c, "move 1", 100)
    assert r.done and total == 10.0 and 11.4 <= r.info["ZPos"] <= 12.5


def test_a_default_world_is_built_under_a_far_placement(run) -> None:
    c = run("far_start.xml")
    r, _ = _steps(c, "", 60)
    assert r.info["XPos"] == -310.5 and r.info["ZPos"] == 150.5
    assert r.info["YPos"] < 81.0 and r.info["IsAlive"]  # fell onto the ground, hurt
    r, total = _steps(c, "", 600)  # time up: RewardForMissionEnd "timeout"
    assert r.done and total == -7.0


def test_pen_chase_observes_its_fences_animals_and_pays_on_the_brick(run) -> None:
    c = run("pen_chase.xml")
    r = c.step("")
    pen = r.info["pen"]  # absolute: x 0..6, z 0..6 at y = 3
    assert len(pen) == 49 and pen[5 * 7 + 5] == "brick_block" and pen[0] == "clay"
    assert {"Herder", "Pig", "Chicken"} <= {e["name"] for e in r.info["animals"]}
    total = r.reward
    for cmd in ["movesouth 1"] * 4 + ["moveeast 1"] * 4:  # (1.5, 1.5) -> (5.5, 5.5)
        r = c.step(cmd)
        total += r.reward
    assert r.done and total == 5.0 - 8.0  # the brick once, minus one per handled command


def test_lava_bridge_pays_on_the_lapis(run) -> None:
    c = run("lava_bridge.xml")
    r, total = _steps(c, "movesouth 1", 12)
    assert r.done and total == 100.0


def test_snacks_fall_from_the_sky_and_are_collected(run) -> None:
    c = run("snack_field.xml")
    _steps(c, "", 40)  # the apple and cookie fall 37 blocks
    r, total = _steps(c, "move 1", 40)
    counts = {s["type"]: s["quantity"] for s in _inventory(r.info)}
    assert counts == {"apple": 1, "cookie": 1} and total == 1.0


def _inventory(info: dict) -> list[dict]:
    return [
        {"type": info[f"InventorySlot_{i}_item"], "quantity": info[f"InventorySlot_{i}_size"]}
        for i in range(41)
        if info[f"InventorySlot_{i}_size"]
    ]


def test_glass_arena_times_out_with_its_mission_end_reward(run) -> None:
    c = run("glass_arena.xml")
    r, total = _steps(c, "", 400)
    assert r.done and total == -1.0


def test_a_pig_in_a_dead_end_is_caught(run) -> None:
    c = run("corner_the_pig.xml")
    r = c.step("")  # the agent blocks the only way out from the first tick
    assert r.done and r.reward == 10.0 + 1.0  # catching, then the quit code "caught"
