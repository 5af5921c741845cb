"""The MalmoEnv wire protocol against a real server: framing, every message type in
Malmo's and MineRL's dialects, and malformed input that must close one connection
without hurting the server."""

from __future__ import annotations

import json
import socket
import time

import pytest

from minecraft.malmo import protocol as P
from minecraft.sim.server import WorldServer
from tests.minecraft.conftest import flat_mission, init_reply, received_until_closed

FRAME = 16 * 12 * 3  # flat_mission(video=True)


def _connect(server: WorldServer, hello: bytes = P.HELLO.encode()) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    P.send(s, hello)
    return s


def _init(s: socket.socket, xml: str, token: str = "exp:0:1:1") -> tuple[int, str]:
    """MissionInit; Malmo answers ok and a turn key, MineRL (5-field token) ok alone."""
    P.send(s, P.mission_init_xml(xml, "exp").encode(), token.encode())
    return init_reply(s, minerl=len(token.split(":")) > 4)


def _peek_until_frame(s: socket.socket) -> bytes:
    """Peek (Malmo: frame, done) until the world has loaded."""
    for _ in range(100):  # each Peek waits up to wait_s for a frame
        P.send(s, b"<Peek/>")
        frame, done = P.recv(s), P.recv(s)
        assert done == b"\x00"
        if frame:
            return frame
    raise AssertionError("no frame after 100 peeks")


def _closed(s: socket.socket) -> bool:
    """The server closed the connection, after at most one ``error: ...`` message."""
    try:
        data = received_until_closed(s, 5)
    except TimeoutError:
        return False
    return data == b"" or (data[4:].startswith(b"error: ") and P.frame(data[4:]) == data)


def test_framing_round_trip_and_size_limit() -> None:
    a, b = socket.socketpair()
    with a, b:
        P.send(a, b"hello", b"", "wörld".encode())
        assert P.recv(b) == b"hello"
        assert P.recv(b) == b""
        assert P.recv(b).decode() == "wörld"
        P.send(a, b"x" * 100)
        with pytest.raises(P.ProtocolError, match="exceeds the limit of 10 bytes"):
            P.recv(b, max_len=10)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("u:0:3:1", P.Token("u", 0, 3, 1, None, None)),
        ("u:0:3:1:true", P.Token("u", 0, 3, 1, True, None)),
        ("u:0:3:1:false:42", P.Token("u", 0, 3, 1, False, 42)),
    ],
)
def test_token_fields(text: str, expected: P.Token) -> None:
    assert P.Token.parse(text) == expected
    assert P.Token.parse(expected.encode()) == expected


def test_step_message_parsing_keeps_malmo_space_and_newlines() -> None:
    msg = P.step_message("move 1\nturn -0.5\n", 2).decode()
    assert msg == "<Step2>move 1\nturn -0.5\n</Step2 >"
    assert P.parse_step(msg) == (2, ["move 1", "turn -0.5"])
    # As Malmo's server reads them: options 4..9 mean neither turn key nor info, and the
    # last 9 characters are the closing tag, so one without the space cuts a character.
    assert P.parse_step("<Step7>move 1</Step7 >") == (7, ["move 1"])
    assert P.step_flags(7) == (False, False)
    assert P.parse_step("<Step2>turn 1</Step2>") == (2, ["turn"])
    for bad in ("<Stepx>move 1</Stepx >", "<Step0>move 1", "<Step0>move 1</Step0 >\n"):
        with pytest.raises(P.ProtocolError):
            P.parse_step(bad)


def test_every_message_type_malmo(server: WorldServer) -> None:
    s = _connect(server)
    with s:
        assert _init(s, flat_mission(video=True)) == (1, "")
        # Peek: frame (16×12×3) and a one-byte done flag, empty while loading.
        assert len(_peek_until_frame(s)) == FRAME
        # Step0: frame, record, info, turn key (a turn key message follows the step).
        P.send(s, P.step_message("move 1", 0), b"")
        assert len(P.recv(s)) == FRAME
        reward, done, sent = P.unpack_step_record(P.recv(s))
        assert (reward, done, sent) == (0.0, False, True)
        P.recv(s)  # info: JSON, or empty when no tick came since the last step
        assert P.recv(s) == b""
        # Step1: turn key, no info.  Step2: info, no turn key.  Step3: neither.
        P.send(s, P.step_message("", 1), b"")
        P.recv(s), P.recv(s)
        assert P.recv(s) == b""
        P.send(s, P.step_message("", 2))
        P.recv(s), P.recv(s)
        info = P.recv(s)
        assert info == b"" or json.loads(info)["TotalTime"] >= 1
        P.send(s, P.step_message("", 3))
        P.recv(s)
        assert len(P.recv(s)) == 10
        P.send(s, b"<Find>exp:0:1</Find>")
        assert P.unpack_int(P.recv(s)) == server.port
        P.send(s, b"<Status/>")
        status = json.loads(P.recv(s))
        assert status["mission_running"] and not status["synchronous"]
        assert status["timing"] == "real" and status["phase"] == "running"
        P.send(s, b"<Echo>hi</Echo>")
        assert P.recv(s) == b"<Echo><Echo>hi</Echo></Echo>"
        for _ in range(500):  # the quit is applied at the next tick
            P.send(s, b"<Quit/>")
            if P.unpack_int(P.recv(s)) == 1:
                break
            time.sleep(0.01)
        else:
            raise AssertionError("the mission never quit")
        P.send(s, P.step_message("move 1", 2))
        P.recv(s)
        assert P.unpack_step_record(P.recv(s))[1] is True  # done
        P.recv(s)
        P.send(s, b"<Close>exp:0:1</Close>")
        assert P.unpack_int(P.recv(s)) == 1
        P.send(s, b"<Init>exp:0:1</Init>")
        assert P.unpack_int(P.recv(s)) == 1
        P.send(s, b"<Exit>exp:0:1</Exit>")
        assert P.unpack_int(P.recv(s)) == 1


def test_every_message_type_minerl(server: WorldServer) -> None:
    s = _connect(server)
    with s:
        assert _init(s, flat_mission(video=True), "exp:0:1:1:true:42") == (1, "")
        # Peek: frame, info, done; MineRL blocks until the world has loaded.
        P.send(s, b"<Peek/>")
        assert len(P.recv(s)) == FRAME
        assert json.loads(P.recv(s))["TotalTime"] == 0
        assert P.recv(s) == b"\x00"
        # StepClient0: frame, record, info; StepServer: no reply. One tick per step.
        for t in (1, 2):
            P.send(s, P.step_client_message("move 1", 0), P.STEP_SERVER)
            assert len(P.recv(s)) == FRAME
            assert P.unpack_step_record(P.recv(s)) == (0.0, False, True)
            assert json.loads(P.recv(s))["TotalTime"] == t
        P.send(s, P.step_client_message("", 1), P.STEP_SERVER)  # option 1: no info
        P.recv(s)
        assert len(P.recv(s)) == 10
        P.send(s, b"<Status/>")
        status = json.loads(P.recv(s))
        assert status["synchronous"] and status["tick"] == 3 and status["seed"] == 42
        P.send(s, b"<Quit/>")
        assert P.unpack_int(P.recv(s)) == 1  # synchronous: the quit is applied at once


@pytest.mark.parametrize(
    ("token", "wrong"),
    [("exp:0:1:1:true", P.step_message("move 1", 2)), ("exp:0:1:1", b"<StepServer></StepServer>")],
)
def test_the_other_dialects_steps_close_the_connection(
    server: WorldServer, token: str, wrong: bytes
) -> None:
    with _connect(server) as s:
        assert _init(s, flat_mission(video=True), token)[0] == 1
        P.send(s, wrong)
        assert _closed(s)
    assert server.status()["protocol_errors"] == 1


def test_bad_hello_oversized_and_unknown_messages_close_only_that_connection(
    server: WorldServer,
) -> None:
    bad = [
        _connect(server, b"<MalmoEnv0.1.0/>"),
        _connect(server, b"x" * 200),
    ]
    big = _connect(server)
    big.sendall((P.MAX_MESSAGE + 1).to_bytes(4, "big"))
    unknown = _connect(server)
    P.send(unknown, b"<Teleport/>")
    malformed = _connect(server)
    P.send(malformed, b"<Step>move 1</Step >")  # no option digit
    for s in [*bad, big, unknown, malformed]:
        assert _closed(s)
        s.close()
    # The server is unharmed: a new connection runs a mission.
    with _connect(server) as s:
        assert _init(s, flat_mission()) == (1, "")
    assert server.status()["protocol_errors"] == 5


def test_unknown_commands_are_ignored_and_bad_missions_refused_with_reason(
    server: WorldServer,
) -> None:
    with _connect(server) as s:
        ok, reason = _init(s, "<Mission><oops")
        assert ok == 0 and "does not parse" in reason
        ok, reason = _init(s, flat_mission(), "exp:1:1:2")
        assert ok == 0 and "1 AgentSection" in reason
        ok, reason = _init(s, flat_mission(), "exp:0:1:1:false")
        assert ok == 0 and "asynchronous" in reason  # MineRL's async mode never answers
        assert _init(s, flat_mission(), "exp:0:1:1:true")[0] == 1
        P.send(s, P.step_client_message("fly 1\nmove\nmove abc\ncraft", 2), P.STEP_SERVER)
        P.recv(s)
        assert P.unpack_step_record(P.recv(s))[2] is True  # sent, bad commands ignored
        P.recv(s)
    # "fly" unknown; "move" and "move abc" malformed (Malmo's Float.valueOf throws);
    # "craft" with nothing named is handled, as Malmo's SimpleCraft takes it.
    assert server.status()["ignored_commands"] == 3
