"""Compatibility suite: the published ``malmoenv`` client (0.0.8, unchanged) and graft's
client against the simulator in real mode, on Malmo-style missions (``missions/``, valid
against Malmo's schema), through the replies a real Malmo gives while it is not ready:

* MissionInit answered 0 while the Minecraft is busy (running or ending a mission);
* Peek and steps with an empty frame while the world loads;
* steps with an empty info (frames come faster than ticks);
* steps answered sent = 0 (loading; no VideoProducer; not the agent's turn);
* a two-agent mission with role tokens, ``<Find>`` and turn keys.

Delays are short (tens of milliseconds) so the suite stays quick; nothing is timed.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from minecraft.malmo import protocol as P
from minecraft.malmo.client import MalmoClient, MissionRefused
from minecraft.sim.pool import free_port_block, wait_ready
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import Timing
from tests.minecraft.conftest import init_reply

# Real Malmo timing: loading, busy and ending waits (the serial lane, beside the CPU-bound tests).
pytestmark = pytest.mark.serial

MISSIONS = Path(__file__).with_name("missions")
WALK = (MISSIONS / "walk.xml").read_text()
NO_VIDEO = (MISSIONS / "no_video.xml").read_text()
TWO_AGENTS = (MISSIONS / "two_agents_turns.xml").read_text()

# Loading outlasts a Peek's wait, so the first Peek really is empty; ending outlasts a
# client's quit-then-MissionInit, so the busy reply really happens.
SLOW_START = Timing(loading_s=0.4, ending_s=1.0, fps=60.0, wait_s=0.15)


def _malmoenv():  # type: ignore[no-untyped-def]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import malmoenv
    return malmoenv


@pytest.fixture
def server() -> Iterator[WorldServer]:
    with WorldServer(port=0, seed=3, timing=SLOW_START) as s:
        yield s


def _connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=10)
    P.send(s, P.HELLO.encode())
    return s


def _init(s: socket.socket, xml: str, token: str) -> tuple[int, str]:
    P.send(s, P.mission_init_xml(xml, token.split(":")[0]).encode(), token.encode())
    return init_reply(s)


# ------------------------------------------------------------------ the raw replies
def test_loading_gives_empty_frames_and_unsent_steps() -> None:
    with WorldServer(port=0, timing=Timing(loading_s=30.0, wait_s=0.1)) as server:
        with _connect(server.port) as s:
            assert _init(s, WALK, "a:0:1:1") == (1, "")
            P.send(s, b"<Peek/>")
            assert (P.recv(s), P.recv(s)) == (b"", b"\x00")  # still loading: no frame yet
            P.send(s, P.step_message("move 1", 2))
            frame, record, info = P.recv(s), P.recv(s), P.recv(s)
            assert (frame, info) == (b"", b"")
            assert P.unpack_step_record(record) == (0.0, False, False)  # sent = 0
            assert server.status()["phase"] == "loading"


def test_busy_while_running_and_while_ending(server: WorldServer) -> None:
    with _connect(server.port) as a, _connect(server.port) as b:
        assert _init(a, WALK, "a:0:1:1")[0] == 1
        # Malmo's busy reply: 0 and an empty turn key; graft's <Status/> says why.
        assert _init(b, WALK, "b:0:1:1") == (0, "")
        assert server.status()["last_refusal"].startswith("busy: a mission is")
        # Malmo's MALMOBUSY asks the running mission to quit: it ends once loaded ...
        for _ in range(200):
            P.send(a, b"<Peek/>")
            P.recv(a)
            if P.recv(a) == b"\x01":
                break
        else:
            raise AssertionError("the busy reply did not end the running mission")
        # ... and the Minecraft stays busy while the mission ends.
        assert _init(b, WALK, "b:0:1:1") == (0, "")
        assert server.status()["last_refusal"].startswith("busy: the previous mission is")
    assert server.status()["busy_replies"] == 2


def test_steps_without_a_video_producer_are_never_sent(server: WorldServer) -> None:
    with _connect(server.port) as s:
        assert _init(s, NO_VIDEO, "a:0:1:1")[0] == 1
        for _ in range(6):  # through loading and into the running mission
            P.send(s, P.step_message("move 1", 2))
            frame, record, _ = P.recv(s), P.recv(s), P.recv(s)
            assert frame == b"" and P.unpack_step_record(record)[2] is False
        assert server.status()["phase"] == "running"


# ------------------------------------------------------------------ both clients
def test_malmoenv_rides_out_loading_busy_and_empty_info(server: WorldServer) -> None:
    env = _malmoenv().make()
    env.init(WALK, server.port, reshape=True)
    first = env.reset()  # peeks through the loading
    assert first.shape == (24, 32, 3) and first.any()
    infos = [env.step(0)[3] for _ in range(20)]
    assert "" in infos  # more frames (60/s) than ticks (4/s): some steps bring no info
    assert all(i == "" or "TotalTime" in json.loads(i) for i in infos)
    second = env.reset()  # quits, then MissionInit is answered 0 while the mission ends
    assert second.shape == (24, 32, 3)
    assert server.status()["busy_replies"] >= 1 and server.status()["missions_started"] == 2
    env.close()


def test_graft_client_rides_out_loading_busy_and_empty_info(server: WorldServer) -> None:
    c = MalmoClient("127.0.0.1", server.port, timeout=10)
    c.init(WALK)
    first = c.reset()
    assert first.shape == (24, 32, 3) and first.any()
    replies = [c.step("move 1") for _ in range(20)]
    assert all(r.sent for r in replies)
    assert any(r.info == {} for r in replies) and c.last_info["TotalTime"] >= 1
    assert c.observe().info["TotalTime"] >= 1
    c.reset()
    assert c.busy_replies >= 1 and server.status()["missions_started"] == 2
    c.close()


def test_a_second_client_waits_until_the_first_mission_quits(server: WorldServer) -> None:
    first = MalmoClient("127.0.0.1", server.port, timeout=10)
    first.init(WALK)
    first.reset()
    env = _malmoenv().make()
    env.init(WALK, server.port, reshape=True)
    assert env.reset().any()  # answered 0 (busy) until the first mission ended
    assert server.status()["missions_started"] == 2 and server.status()["busy_replies"] >= 1
    second = MalmoClient("127.0.0.1", server.port, timeout=10)
    second.init(WALK)
    second.reset()  # env's mission is asked to quit in turn
    assert second.busy_replies >= 1 and server.status()["missions_started"] == 3
    for c in (first, second):
        c.close()
    env.close()


def test_graft_client_names_the_missing_video_producer(server: WorldServer) -> None:
    c = MalmoClient("127.0.0.1", server.port, timeout=10)
    c.init(NO_VIDEO)
    frame = c.reset()  # no frame will ever come: reset returns the empty one
    assert frame.shape == (0, 0, 3)
    with pytest.raises(MissionRefused, match="VideoProducer"):
        c.step("move 1")
    c.close()
    # The published client refuses such a mission before sending it.
    with pytest.raises(AssertionError):
        _malmoenv().make().init(NO_VIDEO, server.port)


def test_graft_client_gives_up_on_a_busy_minecraft() -> None:
    with WorldServer(port=0, timing=Timing(loading_s=30.0, wait_s=0.15)) as server:
        with _connect(server.port) as s:
            assert _init(s, WALK, "other:0:1:1")[0] == 1  # loads for 30 s
            c = MalmoClient("127.0.0.1", server.port, timeout=10, mission_timeout=0.5)
            c.init(WALK)
            # Malmo answers 0 without a reason; graft's simulator says why in <Status/>.
            with pytest.raises(MissionRefused, match="answered 0 for .*last_refusal"):
                c.reset()
            assert c.busy_replies >= 2  # retried with backoff before giving up
            c.close()


# ------------------------------------------------------------------ two agents, turns
def _z(server: WorldServer) -> float:
    w = server.inst.world
    assert w is not None
    return w.player.body.z


TURNS = 3


def test_two_graft_clients_take_turns(
    two_servers: list[WorldServer], run_together: Callable[..., None]
) -> None:
    head = ("127.0.0.1", two_servers[0].port)
    clients = [
        MalmoClient("127.0.0.1", s.port, role=k, exp_uid="duo", head=head, timeout=10)
        for k, s in enumerate(two_servers)
    ]
    for c in clients:
        c.init(TWO_AGENTS)
    assert all(c.turn_based and c.agent_count == 2 for c in clients)
    numbers: list[list[int]] = [[], []]

    def play(k: int) -> Callable[[], None]:
        def run() -> None:
            c = clients[k]
            assert c.reset().shape == (24, 32, 3)
            for _ in range(TURNS):
                r = c.step("move 1")  # resent until it is this agent's turn
                assert r.sent
                if "turn_number" in r.info:
                    numbers[k].append(r.info["turn_number"])

        return run

    run_together(play(0), play(1))
    # Role 0's next turn comes only once role 1's last move ran.
    assert clients[0].step("turn 1").sent
    # Each agent moved exactly TURNS blocks: every move ran with its turn key, once.
    assert [_z(s) for s in two_servers] == [0.5 + TURNS, 0.5 + TURNS]
    assert all(b > a for ns in numbers for a, b in zip(ns, ns[1:], strict=False))
    # Quitting one agent's mission ends the mission for both.
    clients[0].quit()
    assert clients[1].observe().done
    for c in clients:
        c.close()


def test_two_malmoenv_clients_take_turns(
    two_servers: list[WorldServer], run_together: Callable[..., None]
) -> None:
    malmoenv = _malmoenv()
    head = two_servers[0].port
    envs = [malmoenv.make() for _ in two_servers]
    for k, (env, s) in enumerate(zip(envs, two_servers, strict=True)):
        env.init(TWO_AGENTS, head, port2=s.port, role=k, exp_uid="duo", reshape=True)
    actions = [list(env.action_space.actions) for env in envs]

    def play(k: int) -> Callable[[], None]:
        def run() -> None:
            env = envs[k]
            obs = env.reset()  # role 1 finds role 0's mission with <Find>
            assert obs.shape == (24, 32, 3)
            # The published client steps with an empty turn key until a reply gives it
            # one; out of turn Malmo queues such a step (sent = 1) and TurnBasedCommands
            # drops it. Only steps after which it holds a key took a turn.
            turns = 0
            while turns < TURNS:
                obs, _, done, _ = env.step(actions[k].index("move 1"))
                assert not done
                turns += env.turn_key != ""
            if k == 0:  # a last turn, which comes only once role 1's last move ran
                env.step(actions[k].index("turn 1"))

        return run

    run_together(play(0), play(1))
    assert [_z(s) for s in two_servers] == [0.5 + TURNS, 0.5 + TURNS]
    for env in envs:
        env.close()


def test_a_turn_based_step_out_of_turn_is_not_sent(
    two_servers: list[WorldServer], run_together: Callable[..., None]
) -> None:
    head = ("127.0.0.1", two_servers[0].port)
    clients = [
        MalmoClient("127.0.0.1", s.port, role=k, exp_uid="solo", head=head, timeout=10,
                    step_timeout=0.3)
        for k, s in enumerate(two_servers)
    ]  # fmt: skip
    for c in clients:
        c.init(TWO_AGENTS)

    def reset(k: int) -> Callable[[], None]:
        def run() -> None:
            clients[k].reset()

        return run

    run_together(reset(0), reset(1))
    assert clients[0].step("move 1").sent  # the first turn is role 0's (requestedPosition 1)
    with pytest.raises(TimeoutError, match="not this agent's turn"):
        clients[0].step("move 1")  # the next is role 1's, which has not acted
    assert clients[1].step("move 1").sent  # role 1 gets its key once role 0's move ran
    assert np.isclose(_z(two_servers[0]), 1.5)  # role 0 moved once, not twice
    for c in clients:
        c.close()


@pytest.mark.service
def test_two_agents_against_minecraft_serve_with_two_instances(
    run_together: Callable[..., None],
) -> None:
    base = free_port_block(2)
    root = str(Path(__file__).resolve().parents[3])
    cmd = [
        sys.executable, "-m", "minecraft.cli", "minecraft", "serve",
        "--port", str(base), "--instances", "2", "--loading-s", "0.05", "--ending-s", "0.05",
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        for port in (base, base + 1):
            wait_ready("127.0.0.1", port)
        clients = [
            MalmoClient("127.0.0.1", base + k, role=k, exp_uid="pair", timeout=10) for k in range(2)
        ]  # role 1 finds role 0 at base + 1 - 1, as Malmo's samples number their ports

        def play(k: int) -> Callable[[], None]:
            def run() -> None:
                clients[k].init(TWO_AGENTS)
                clients[k].reset()
                assert clients[k].step("move 1").sent

            return run

        run_together(play(0), play(1))
        assert clients[0].step("turn 1").sent  # role 0's second turn: role 1 has moved
        for c in clients:
            c.close()
    finally:
        proc.terminate()
        proc.wait(10)
