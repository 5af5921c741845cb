"""graft's MalmoEnv client: the same code talks to the simulator and to a real Malmo
Minecraft (``launchClient.sh -port 9000 -env``), or a MineRL one (``synchronous=True``).

Typical loop::

    client = MalmoClient("127.0.0.1", 9000)
    client.init(mission_xml)
    frame = client.reset()               # H×W×C uint8, top row first
    while True:
        r = client.step("move 1\\nturn 0.2")
        info = r.info or client.last_info  # a step may bring no new observation
        if r.done:
            break
    client.close()

What it tolerates, as Malmo's own ``malmoenv`` client does where Malmo documents it:

* a MissionInit answered 0: Malmo is still ending the previous mission or loading (it
  asks a running one to quit); retried with exponential backoff for ``mission_timeout``
  seconds, then ``MissionRefused`` (Malmo gives no reason); a mission graft's simulator
  will never run is answered with one ``error: ...`` message instead, raised at once as
  ``MissionRefused``;
* Peek returning an empty frame while the world loads: ``reset()`` peeks until the
  first real frame (``first_frame_timeout``);
* a step answered sent = 0 (no frame yet, not our turn): resent until accepted
  (``step_timeout``); without a VideoProducer Malmo never accepts one, which raises at
  once;
* an empty ``info``: frames come faster than ticks, so a step may carry no new
  observation; ``StepResult.info`` is then ``{}`` and ``last_info`` keeps the latest;
* a server that went away: ``reset()`` reconnects with backoff.

Multi-agent missions: one client per role, sharing ``exp_uid``; role k talks to its own
Minecraft and finds role 0's mission through ``head`` (role 0's address), as Malmo's
samples do with ports 9000 + k. Turn-based missions carry Malmo's turn keys.
"""

from __future__ import annotations

import json
import re
import socket
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from minecraft.malmo import protocol as P
from minecraft.malmo.mission import Mission, parse_mission
from minecraft.malmo.roles import role_mission


class MissionRefused(RuntimeError):
    """The server would not start the mission (the message carries its reason)."""


class NotReady(TimeoutError):
    """The server kept answering "not yet" (no frame, not our turn, not ended) for
    longer than the client's bound; the message says what it waited for."""


@dataclass
class StepResult:
    """One step's reply.

    Attributes:
        frame: H×W×C uint8 (top row first), or an empty (0, 0, C) array when no frame
            came with the reply.
        reward: rewards summed since the previous step collected them.
        done: the mission has ended.
        info: the observation producers' JSON, ``{}`` when no new observation came.
        sent: the server queued the commands (otherwise they were not applied).
    """

    frame: np.ndarray
    reward: float
    done: bool
    info: dict[str, Any] = field(default_factory=dict)
    sent: bool = True


NO_KEY = "NOKEY"  # never a turn key (Malmo's are five lower-case letters)
_DEFAULT_GEN = re.compile(r"<DefaultWorldGenerator\b([^>]*?)(/?)>")


def with_seed(mission_xml: str, seed: int) -> str:
    """The mission with ``seed`` on its DefaultWorldGenerator (how Malmo takes a seed)."""

    def put(m: re.Match[str]) -> str:
        attrs = re.sub(r'\sseed="[^"]*"', "", m.group(1))
        return f'<DefaultWorldGenerator{attrs} seed="{seed}"{m.group(2)}>'

    return _DEFAULT_GEN.sub(put, mission_xml, count=1)


class MalmoClient:
    """A MalmoEnv connection to one Minecraft (simulated or real).

    Args:
        host: this agent's Minecraft address.
        port: this agent's Minecraft port.
        synchronous: speak MineRL's synchronous dialect (one tick per step).
        seed: the world seed: MineRL's token field, or written into the mission's
            DefaultWorldGenerator for Malmo.
        role: this agent's role in a multi-agent mission (its AgentSection).
        exp_uid: the experiment id all roles share (default: a fresh uuid).
        head: role 0's (host, port), where a role > 0 finds the mission (default: this
            host, ``port - role``).
        timeout: socket timeout in seconds.
        max_backoff: the longest pause between retries, in seconds.
        connect_attempts: attempts before ``connect()`` gives up.
        mission_timeout: seconds of MissionInit answered 0 (and of quitting) before
            ``reset()`` gives up.
        first_frame_timeout: seconds ``reset()`` waits for the first frame.
        step_timeout: seconds a step is resent while the server answers sent = 0.
        info_decoder: turns a non-empty info JSON (bytes) into ``StepResult.info``
            (default ``json.loads``; e.g. ``grid_encoding.GridInfo`` for block ids).
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = P.DEFAULT_PORT,
        *,
        synchronous: bool = False,
        seed: Optional[int] = None,
        role: int = 0,
        exp_uid: Optional[str] = None,
        head: Optional[tuple[str, int]] = None,
        timeout: float = 30.0,
        max_backoff: float = 5.0,
        connect_attempts: int = 10,
        mission_timeout: float = 120.0,
        first_frame_timeout: float = 180.0,
        step_timeout: float = 120.0,
        info_decoder: Callable[[bytes], dict[str, Any]] = json.loads,
    ) -> None:
        self.host, self.port = host, port
        self.synchronous, self.seed, self.role = synchronous, seed, role
        self.head = head if head is not None else (host, port - role)
        self.timeout, self.max_backoff, self.connect_attempts = (
            timeout,
            max_backoff,
            connect_attempts,
        )
        self.mission_timeout = mission_timeout
        self.first_frame_timeout = first_frame_timeout
        self.step_timeout = step_timeout
        self.info_decoder = info_decoder
        self.exp_uid = exp_uid if exp_uid is not None else str(uuid.uuid4())
        self.resets = 0
        self.done = True
        self.mission: Optional[Mission] = None
        self.agent_count = 1
        self.turn_based = False
        self.turn_key = ""
        self.last_info: dict[str, Any] = {}
        self._xml = ""
        self._sock: Optional[socket.socket] = None
        self.reconnects = 0
        self.busy_replies = 0

    # ---------------------------------------------------------------- plumbing
    def _open(self, address: Optional[tuple[str, int]] = None) -> socket.socket:
        s = socket.create_connection(address or (self.host, self.port), timeout=self.timeout)
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        P.send(s, P.HELLO.encode())
        return s

    def connect(self) -> None:
        """Connect (if not connected), retrying with exponential backoff.

        Raises:
            ConnectionError: the server stayed unreachable for all attempts.
        """
        if self._sock is not None:
            return
        delay, last = 0.05, None
        for _ in range(self.connect_attempts):
            try:
                self._sock = self._open()
                return
            except OSError as e:
                last = e
                time.sleep(delay)
                delay = min(delay * 2, self.max_backoff)
        raise ConnectionError(f"cannot reach world server {self.host}:{self.port}: {last}")

    def _drop(self) -> None:
        if self._sock is not None:
            try:
                self._sock.close()
            except OSError:
                pass
            self._sock = None

    def _call(self, *payloads: bytes) -> socket.socket:
        if self._sock is None:
            raise ConnectionError("not connected; call reset()")
        P.send(self._sock, *payloads)
        return self._sock

    # ----------------------------------------------------------------- mission
    def init(self, mission_xml: str, *, episode: int = 0) -> None:
        """Set the mission for the following resets (no traffic yet).

        Raises:
            MissionError: the XML cannot be used (or has no AgentSection for ``role``).
        """
        if self.seed is not None and not self.synchronous:
            mission_xml = with_seed(mission_xml, self.seed)
        role = role_mission(mission_xml, self.role)
        self.mission = parse_mission(role.xml)
        self.agent_count = role.agent_count
        self.turn_based = role.turn_position is not None
        self._xml = mission_xml
        self.resets = episode

    def _token(self) -> str:
        sync = self.synchronous if self.synchronous else None
        seed = self.seed if self.synchronous else None
        return P.Token(self.exp_uid, self.role, self.resets, self.agent_count, sync, seed).encode()

    @property
    def _key(self) -> str:
        return f"{self.exp_uid}:{self.role}:{self.resets}"

    def reset(self) -> np.ndarray:
        """End any running episode and start a new one; returns the first frame.

        Reconnects (with backoff) if the server went away.

        Raises:
            MissionRefused: the server refused the mission, or stayed busy for
                ``mission_timeout`` seconds (its reason included).
            NotReady: no first frame within ``first_frame_timeout`` seconds.
        """
        if not self._xml:
            raise RuntimeError("call init(mission_xml) before reset()")
        for attempt in range(2):
            try:
                if not self.done and self._sock is not None:
                    self.quit()
                self.resets += 1
                server = self._find() if self.role > 0 else None
                self.connect()
                self._start(server)
                return self._first_frame()
            except NotReady:
                raise
            except (OSError, ConnectionError, P.ProtocolError):
                self._drop()
                self.reconnects += 1
                if attempt == 1:
                    raise
        raise AssertionError("unreachable")

    def _find(self) -> tuple[str, int]:
        """Ask role 0's service where its mission runs (Malmo's ``<Find>``)."""
        deadline = time.monotonic() + self.mission_timeout
        s = self._open(self.head)
        try:
            while True:
                P.send(s, f"<Find>{self._key}</Find>".encode())
                port = P.unpack_int(P.recv(s))
                if port != 0:
                    return self.head[0], port
                if time.monotonic() > deadline:
                    raise MissionRefused(
                        f"role 0 at {self.head[0]}:{self.head[1]} started no mission "
                        f"{self._key} in {self.mission_timeout:.0f} s"
                    )
                time.sleep(0.05)
        finally:
            s.close()

    def _start(self, server: Optional[tuple[str, int]]) -> None:
        xml = P.mission_init_xml(self._xml, self.exp_uid, self.role, server=server).encode()
        token = self._token().encode()
        t0 = time.monotonic()
        delay = 0.05
        while True:
            sock = self._call(xml, token)
            first = P.recv(sock)
            if first.startswith(b"error: "):  # graft's simulator: it will never run this
                raise MissionRefused(first.decode("utf-8", "replace"))
            ok = P.unpack_int(first)
            reply = "" if self.synchronous else P.recv(sock).decode("utf-8", "replace")
            if ok == 1:
                # Malmo's initial turn key is empty. A turn-based agent must not step
                # with an empty key: out of turn, Malmo queues such commands and
                # TurnBasedCommands drops them. A key no turn has makes it wait instead.
                self.turn_key = reply or (NO_KEY if self.turn_based else "")
                self.done = False
                self.last_info = {}
                return
            self.busy_replies += 1
            waited = time.monotonic() - t0
            if waited > self.mission_timeout:
                raise MissionRefused(
                    f"MissionInit answered 0 for {waited:.0f} s; Malmo gives no reason: "
                    "still ending or loading a mission, or a mission it cannot run (graft's "
                    "simulator names it in <Status/>'s last_refusal)"
                )
            time.sleep(delay)
            delay = min(delay * 2, self.max_backoff)

    def _first_frame(self) -> np.ndarray:
        """Peek until the world has loaded and the first frame exists."""
        deadline = time.monotonic() + self.first_frame_timeout
        delay = 0.01
        while True:
            frame, done = self.peek()
            if done or frame.size or self.mission is None or not self.mission.has_video:
                return frame
            if time.monotonic() > deadline:
                raise NotReady(f"no first frame in {self.first_frame_timeout:.0f} s")
            time.sleep(delay)
            delay = min(delay * 2, 0.1)

    def _frame(self, data: bytes) -> np.ndarray:
        m = self.mission
        c = m.channels if m is not None else 3
        if not data or m is None or not m.has_video:
            return np.zeros((0, 0, c), dtype=np.uint8)
        # Malmo sends rows bottom-up (OpenGL order); return them top-down.
        return np.frombuffer(data, dtype=np.uint8).reshape(m.height, m.width, c)[::-1]

    def _info(self, raw: bytes) -> dict[str, Any]:
        info = self.info_decoder(raw) if raw else {}
        if info:
            self.last_info = info
        return info

    def peek(self) -> tuple[np.ndarray, bool]:
        """The latest frame without acting or consuming it; (frame, done). The frame is
        empty while the world is still loading."""
        sock = self._call(b"<Peek/>")
        data = P.recv(sock)
        if self.synchronous:
            self._info(P.recv(sock))  # MineRL adds the observation
        done = P.recv(sock) == b"\x01"
        self.done = done
        return self._frame(data), done

    def step(self, commands: str | Sequence[str] = "", *, with_info: bool = True) -> StepResult:
        """Send commands (one string, newline-joined, or a sequence) and get the reply.

        Resent, as malmoenv does, while the server answers sent = 0 (no frame yet, or
        not this agent's turn).

        Raises:
            MissionRefused: the mission has no VideoProducer and the server (like real
                Malmo) never accepts its commands.
            NotReady: not accepted within ``step_timeout`` seconds.
        """
        text = commands if isinstance(commands, str) else "\n".join(commands)
        if self.synchronous:
            return self._step_client(text, with_info)
        # Option 0/1 carries Malmo's turn key (turn-based missions); 2/3 does not.
        opts = (0 if with_info else 1) if self.turn_based else (2 if with_info else 3)
        with_key = opts < 2
        msg = P.step_message(text, opts)
        deadline = time.monotonic() + self.step_timeout
        delay = 0.005
        while True:
            sock = self._call(msg, self.turn_key.encode()) if with_key else self._call(msg)
            data = P.recv(sock)
            reward, done, sent = P.unpack_step_record(P.recv(sock))
            info_raw = P.recv(sock) if with_info else b""
            if with_key:
                key = P.recv(sock).decode("utf-8")
                if key:
                    self.turn_key = key
            self.done = done
            if sent or done:
                return StepResult(self._frame(data), reward, done, self._info(info_raw), sent)
            if not data and self.mission is not None and not self.mission.has_video:
                raise MissionRefused(
                    "the mission has no VideoProducer: Malmo never queues its commands"
                )
            if time.monotonic() > deadline:
                why = "not this agent's turn" if data else "no frame from the server"
                raise NotReady(f"step not accepted in {self.step_timeout:.0f} s: {why}")
            time.sleep(delay)
            delay = min(delay * 2, 0.1)

    def _step_client(self, text: str, with_info: bool) -> StepResult:
        opts = 0 if with_info else 1
        sock = self._call(P.step_client_message(text, opts))
        data = P.recv(sock)
        reward, done, sent = P.unpack_step_record(P.recv(sock))
        info_raw = P.recv(sock) if with_info else b""
        P.send(sock, P.STEP_SERVER)  # advance the server tick; MineRL does not answer
        self.done = done
        return StepResult(self._frame(data), reward, done, self._info(info_raw), sent)

    def observe(self) -> StepResult:
        """Step with no commands until an observation arrives (or the mission ends); the
        rewards of those steps are summed into the result."""
        total = 0.0
        deadline = time.monotonic() + self.step_timeout
        while True:
            r = self.step("")
            total += r.reward
            if r.info or r.done:
                r.reward = total
                return r
            if time.monotonic() > deadline:
                raise NotReady(f"no observation in {self.step_timeout:.0f} s")

    def quit(self) -> None:
        """Ask the server to end the episode and wait until it has.

        Raises:
            NotReady: still not ended after ``mission_timeout`` seconds.
        """
        deadline = time.monotonic() + self.mission_timeout
        delay = 0.01
        while True:
            sock = self._call(b"<Quit/>")
            if P.unpack_int(P.recv(sock)) != 0:
                self.done = True
                return
            if time.monotonic() > deadline:
                raise NotReady(f"the mission did not end in {self.mission_timeout:.0f} s")
            time.sleep(delay)
            delay = min(delay * 2, 0.1)

    def status(self) -> dict[str, Any]:
        """The server's ``<Status/>`` JSON."""
        s = self._open()
        try:
            P.send(s, b"<Status/>")
            return json.loads(P.recv(s).decode("utf-8") or "{}")
        finally:
            s.close()

    def close(self) -> None:
        """Release the token (``<Close>`` to role 0's service) and disconnect."""
        try:
            s = self._open(self.head)
            try:
                P.send(s, f"<Close>{self._key}</Close>".encode())
                P.recv(s)
            finally:
                s.close()
        except OSError:
            pass
        self._drop()
        self.done = True
