"""Where the world server's replies meet ``MalmoEnvServer.java``'s edge cases: each either
matches Java or is a difference docs/minecraft.md records with its reason."""

from __future__ import annotations

import socket
import time

from minecraft.malmo import protocol as P
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.server import WorldServer
from tests.minecraft.conftest import FLAT, connect, flat_mission, received_until_closed


def _reply_then_closed(s: socket.socket) -> bytes:
    """Everything the server sent before it closed ``s``."""
    return received_until_closed(s, 10)


def _running(s: socket.socket) -> None:
    """Start a mission with video on ``s`` and peek until its first frame."""
    P.send(s, P.mission_init_xml(flat_mission(video=True), "exp").encode(), b"exp:0:1:1")
    assert P.unpack_int(P.recv(s)) == 1 and P.recv(s) == b""
    for _ in range(100):
        P.send(s, b"<Peek/>")
        frame, _ = P.recv(s), P.recv(s)
        if frame:
            return
    raise AssertionError("no frame")


def test_quit_before_any_mission_answers_done_unlike_java(server: WorldServer) -> None:
    # Java answers 0 (its done starts false and nothing will end), so a client that
    # repeats <Quit/> until 1 would spin for ever; malmoenv sends none before its
    # first mission. graft answers 1: there is nothing to end.
    with connect(server.port) as s:
        P.send(s, b"<Quit/>")
        assert P.unpack_int(P.recv(s)) == 1


def test_a_step_option_above_3_is_step3_as_in_java(server: WorldServer) -> None:
    with connect(server.port) as s:
        _running(s)
        # Java: Character.getNumericValue('5') = 5, not < 2 (no turn key), not 0 or 2
        # (no info): frame and record only, and the connection stays open.
        P.send(s, b"<Step5>move 1</Step5 >")
        P.recv(s)
        assert len(P.recv(s)) == 10
        P.send(s, b"<Echo/>")
        assert P.recv(s) == b"<Echo><Echo/></Echo>"
    assert server.status()["protocol_errors"] == 0


def test_a_step_without_malmos_space_loses_its_last_character_as_in_java(
    server: WorldServer,
) -> None:
    with connect(server.port) as s:
        _running(s)
        # Java cuts "</StepN >".length() = 9 characters off the end: without the space
        # the command's last character goes, and "move " is a command without a value.
        P.send(s, b"<Step3>move 1</Step3>")
        P.recv(s)
        assert P.unpack_step_record(P.recv(s))[2]  # sent
        t0 = time.monotonic()
        while server.status()["ignored_commands"] < 1:
            assert time.monotonic() - t0 < 5, "the command ran whole"
            time.sleep(0.02)
        P.send(s, b"<Step3>move 1</Step3 >")  # Malmo's own form runs whole
        P.recv(s)
        P.recv(s)
        time.sleep(0.2)
    assert server.status()["ignored_commands"] == 1


def test_a_busy_reply_has_an_empty_turn_key_as_in_java(server: WorldServer) -> None:
    with connect(server.port) as a, connect(server.port) as b:
        _running(a)
        P.send(b, P.mission_init_xml(flat_mission(), "b").encode(), b"b:0:1:1")
        # Java sends 0 and "" (its TODO: initial turn key); the reason is in graft's log
        # and <Status/>.
        assert P.unpack_int(P.recv(b)) == 0
        assert P.recv(b) == b""
    assert str(server.status()["last_refusal"]).startswith("busy: a mission is")


def test_a_mission_that_can_never_run_is_refused_with_one_error_message(
    server: WorldServer,
) -> None:
    # Java answers 0 and clients retry for ever; graft sends one `error: ...` message in
    # place of the ok int (malmoenv's init raises on it), and the connection stays open.
    too_big = mission_xml(width=4000, height=3000, flat=FLAT)
    cases = [
        (too_big, "e:0:1:1", "(--max-frame-pixels)"),
        (too_big, "e:0:2:1:true", "(--max-frame-pixels)"),  # MineRL's dialect too
        ("<Mission>", "e:0:3:1", "does not parse"),
        (flat_mission(), "e", "needs exp_uid:role:reset:agent_count"),
    ]
    with connect(server.port) as s:
        for xml, token, why in cases:
            P.send(s, P.mission_init_xml(xml, "e").encode(), token.encode())
            reply = P.recv(s).decode()
            assert reply.startswith("error: ") and why in reply, reply
            assert server.status()["last_refusal"] == reply
        P.send(s, b"<Echo/>")
        assert P.recv(s) == b"<Echo><Echo/></Echo>"  # nothing else was sent
    assert server.status()["busy_replies"] == 0


def test_a_bad_hello_or_unknown_command_gets_one_error_message_then_close_unlike_java(
    server: WorldServer,
) -> None:
    # Java closes without a word; graft says why first (a client that does not read it
    # sees the same closed connection).
    for hello, request in ((b"<MalmoEnv0.36.0/>", b""), (P.HELLO.encode(), b"<Fly/>")):
        with socket.create_connection(("127.0.0.1", server.port), timeout=10) as s:
            P.send(s, hello)
            if request:
                P.send(s, request)
            data = _reply_then_closed(s)
            assert data[4:].startswith(b"error: ") and P.frame(data[4:]) == data
