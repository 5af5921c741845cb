"""The MalmoEnv wire protocol, shared by graft's server and client.

Every message, both ways, is a 4-byte big-endian length then the payload. A connection
opens with the hello ``<MalmoEnv0.37.0/>``. Requests are XML-ish strings
(``<MissionInit ...>`` followed by a token message, ``<Peek/>``,
``<StepN>commands</StepN >``, ``<Quit/>``, ``<Close>token</Close>``, ``<Init>token</Init>``,
``<Exit>token</Exit>``, ``<Find>token</Find>``, ``<Status/>``, ``<Echo...>``); replies are
binary (int32 flags, raw frames, a 10-byte ``!dbb`` reward/done/sent record) and UTF-8
strings (info JSON, turn keys), each framed the same way.

Two dialects share the framing. Malmo's (the token ``exp_uid:role:reset:agent_count``):
MissionInit is answered with ok and a turn key, Peek with frame and done, ``<StepN>``
with frame, record, info and turn key as N asks. MineRL's fork (a token with a 5th field
``synchronous`` true/false and an optional 6th, the world seed): MissionInit is answered
with ok alone, Peek with frame, info and done, and a synchronous step is
``<StepClientN>commands</StepClientN >`` (answered with frame, record and, for N in
{0, 2}, info) followed by ``<StepServer></StepServer>`` (not answered).
"""

from __future__ import annotations

import re
import socket
import struct
from dataclasses import dataclass
from typing import Optional

VERSION = "0.37.0"
HELLO = f"<MalmoEnv{VERSION}/>"
HELLO_PREFIX = "<MalmoEnv"
MAX_HELLO = len(HELLO_PREFIX) + 8  # Malmo refuses longer hellos
MAX_MESSAGE = 16 * 1024 * 1024  # the longest reply a client reads (frames included)
CHUNK = 1 << 16  # the most read from a socket at once
DEFAULT_PORT = 9000

_LEN = struct.Struct("!I")
_INT = struct.Struct("!i")
_STEP_RECORD = struct.Struct("!dbb")
_STEP_RE = re.compile(r"<Step([0-9])>(.*)</Step[0-9]?\s*>\Z", re.DOTALL)
_STEP_CUT = len("</Step0 >")  # what Malmo's server cuts off the end of a step message
_STEP_CLIENT_RE = re.compile(r"<StepClient([0-3])>(.*)</StepClient\1\s*>\s*$", re.DOTALL)
STEP_SERVER = b"<StepServer></StepServer>"


class ProtocolError(Exception):
    """A peer broke the protocol (bad hello, oversized or unknown message); the message
    says what was wrong. The server closes that one connection, as Malmo does."""


class ConnectionClosed(ConnectionError):
    """The peer closed the connection."""


def frame(payload: bytes) -> bytes:
    """One framed message."""
    return _LEN.pack(len(payload)) + payload


def send(sock: socket.socket, *payloads: bytes) -> None:
    """Send several framed messages with one system call."""
    sock.sendall(b"".join(_LEN.pack(len(p)) + p for p in payloads))


def recv_exact(sock: socket.socket, n: int) -> bytes:
    """Read exactly ``n`` bytes, holding only those that have arrived (a peer that
    announces a long message and sends nothing costs ``CHUNK`` bytes, not ``n``).

    Raises:
        ConnectionClosed: the peer closed the connection first.
    """
    chunks: list[bytes] = []
    got = 0
    while got < n:
        chunk = sock.recv(min(n - got, CHUNK))
        if not chunk:
            raise ConnectionClosed(f"connection closed after {got} of {n} bytes")
        chunks.append(chunk)
        got += len(chunk)
    return chunks[0] if len(chunks) == 1 else b"".join(chunks)


def recv(sock: socket.socket, max_len: int = MAX_MESSAGE) -> bytes:
    """Read one framed message.

    Raises:
        ProtocolError: the announced length exceeds ``max_len`` (the payload is not read).
        ConnectionClosed: the peer closed the connection.
    """
    (n,) = _LEN.unpack(recv_exact(sock, 4))
    if n > max_len:
        raise ProtocolError(f"message of {n} bytes exceeds the limit of {max_len} bytes")
    return recv_exact(sock, n)


def pack_int(value: int) -> bytes:
    """A big-endian int32 payload (ok flags, ports)."""
    return _INT.pack(value)


def unpack_int(payload: bytes) -> int:
    """Decode an int32 payload.

    Raises:
        ProtocolError: not 4 bytes (the server's ``error: ...`` refusal is quoted).
    """
    if payload.startswith(b"error: "):
        raise ProtocolError(payload.decode("utf-8", "replace"))
    if len(payload) != 4:
        raise ProtocolError(f"expected a 4-byte int, got {len(payload)} bytes")
    return _INT.unpack(payload)[0]


def pack_step_record(reward: float, done: bool, sent: bool) -> bytes:
    """The 10-byte step record: double reward, byte done, byte sent."""
    return _STEP_RECORD.pack(reward, 1 if done else 0, 1 if sent else 0)


def unpack_step_record(payload: bytes) -> tuple[float, bool, bool]:
    """Decode the step record into (reward, done, sent)."""
    if len(payload) != _STEP_RECORD.size:
        raise ProtocolError(f"step record must be 10 bytes, got {len(payload)}")
    reward, done, sent = _STEP_RECORD.unpack(payload)
    return reward, done == 1, sent == 1


def step_flags(options: int) -> tuple[bool, bool]:
    """(with_turn_key, with_info) for Step option 0..9, as Malmo defines them (4..9 are
    read as 3 would be: neither)."""
    return options < 2, options in (0, 2)


def step_message(commands: str, options: int = 0) -> bytes:
    """A step request (note Malmo's space before the closing ``>``)."""
    return f"<Step{options}>{commands}</Step{options} >".encode()


def step_client_message(commands: str, options: int = 0) -> bytes:
    """MineRL's synchronous step request (always followed by ``STEP_SERVER``)."""
    return f"<StepClient{options}>{commands}</StepClient{options} >".encode()


def parse_step(message: str) -> tuple[int, list[str]]:
    """Split a ``<StepN>`` or ``<StepClientN>`` request into its option and commands (one
    per line).

    A ``<StepN>``'s commands are what Malmo's server takes: everything between the
    opening tag and the last 9 characters (``</StepN >``, with Malmo's space), so a
    closing tag without the space costs the commands their last character.

    Raises:
        ProtocolError: the message is not a well-formed step.
    """
    client = message.startswith("<StepClient")
    m = (_STEP_CLIENT_RE if client else _STEP_RE).match(message)
    if m is None:
        raise ProtocolError(f"malformed step message {message[:80]!r}")
    body = m.group(2) if client else message[len("<Step0>") : len(message) - _STEP_CUT]
    return int(m.group(1)), [c.strip() for c in body.split("\n") if c.strip()]


def step_is_cut(message: str) -> bool:
    """Malmo's server cuts into this ``<StepN>``'s commands (no space before ``>``)."""
    return not message.endswith(" >")


def tag_body(message: str, tag: str) -> str:
    """The text between ``<tag>`` and ``</tag>`` (tokens of Close, Init, Exit, Find)."""
    m = re.match(rf"<{tag}>(.*)</{tag}\s*>\s*$", message, re.DOTALL)
    if m is None:
        raise ProtocolError(f"malformed <{tag}> message {message[:80]!r}")
    return m.group(1)


@dataclass(frozen=True)
class Token:
    """A mission token ``exp_uid:role:reset:agent_count[:synchronous[:seed]]``.

    ``synchronous`` is None for Malmo's 4-field token; a value (MineRL's 5th field)
    selects MineRL's dialect. The seed (6th field) needs the 5th.
    """

    exp_uid: str
    role: int
    reset: int
    agent_count: int = 1
    synchronous: Optional[bool] = None
    seed: Optional[int] = None

    def __post_init__(self) -> None:
        if self.seed is not None and self.synchronous is None:
            raise ValueError("a token's seed (6th field) needs the synchronous 5th field")

    @property
    def minerl(self) -> bool:
        """The token carries MineRL's 5th field (the peer speaks MineRL's dialect)."""
        return self.synchronous is not None

    def encode(self) -> str:
        """The token string (5th/6th fields only when set)."""
        s = f"{self.exp_uid}:{self.role}:{self.reset}:{self.agent_count}"
        if self.synchronous is not None:
            s += ":" + ("true" if self.synchronous else "false")
        if self.seed is not None:
            s += f":{self.seed}"
        return s

    @property
    def key(self) -> str:
        """``exp_uid:role:reset``, the part Close, Find and Malmo's token table use."""
        return f"{self.exp_uid}:{self.role}:{self.reset}"

    @staticmethod
    def parse(text: str) -> Token:
        """Parse a token.

        Raises:
            ProtocolError: fewer than 4 fields or non-integer role/reset/count/seed.
        """
        f = text.split(":")
        if len(f) < 4:
            raise ProtocolError(f"token {text!r} needs exp_uid:role:reset:agent_count")
        try:
            seed = int(f[5]) if len(f) > 5 and f[5] else None
            sync = f[4].strip().lower() == "true" if len(f) > 4 else None
            role, reset, count = int(f[1]), int(f[2]), int(f[3])
        except ValueError:
            raise ProtocolError(f"token {text!r} has a non-integer field") from None
        return Token(f[0], role, reset, count, sync, seed)


def mission_init_xml(
    mission_xml: str, exp_uid: str, role: int = 0, *,
    server: Optional[tuple[str, int]] = None,
) -> str:  # fmt: skip
    """Wrap a ``<Mission>`` in the ``<MissionInit>`` element a MalmoEnv client sends.

    ``server`` (address, integrated server port) adds the ``MinecraftServerConnection``
    by which a role > 0 joins role 0's mission.
    """
    i = mission_xml.find("<Mission")
    if i < 0:
        raise ValueError("mission XML must contain a <Mission> element")
    body = mission_xml[i:]
    join = ""
    if server is not None:
        join = f'<MinecraftServerConnection address="{server[0]}" port="{server[1]}"/>'
    return (
        '<MissionInit xmlns="http://ProjectMalmo.microsoft.com" '
        'xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
        f'SchemaVersion="" PlatformVersion="{VERSION}">'
        f"{body}<ExperimentUID>{exp_uid}</ExperimentUID>{join}<ClientRole>{role}</ClientRole>"
        "<ClientAgentConnection><ClientIPAddress>127.0.0.1</ClientIPAddress>"
        "<ClientMissionControlPort>0</ClientMissionControlPort>"
        "<ClientCommandsPort>0</ClientCommandsPort><AgentIPAddress>127.0.0.1</AgentIPAddress>"
        "<AgentMissionControlPort>0</AgentMissionControlPort><AgentVideoPort>0</AgentVideoPort>"
        "<AgentDepthPort>0</AgentDepthPort><AgentLuminancePort>0</AgentLuminancePort>"
        "<AgentObservationsPort>0</AgentObservationsPort><AgentRewardsPort>0</AgentRewardsPort>"
        "<AgentColourMapPort>0</AgentColourMapPort></ClientAgentConnection></MissionInit>"
    )
