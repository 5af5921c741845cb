"""graft's MalmoEnv client: the same code talks to the simulator and to a real Malmo
Minecraft (``launchClient.sh -port 9000 -env``).

Typical loop::

    client = MalmoClient("127.0.0.1", 9000, synchronous=True)
    client.init(mission_xml)
    obs = client.reset()                 # frame H×W×C uint8, top row first
    while True:
        r = client.step("move 1\\nturn 0.2")
        if r.done:
            break
    client.close()

``reset()`` reconnects with exponential backoff when the server went away, so an actor
survives a world server restart by resetting.
"""

from __future__ import annotations

import json
import socket
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from actors.minecraft.malmo import protocol as P
from actors.minecraft.malmo.mission import Mission, parse_mission


class MissionRefused(RuntimeError):
    """The server would not start the mission (the message carries its reason)."""


@dataclass
class StepResult:
    """One step's reply.

    Attributes:
        frame: H×W×C uint8 (top row first), or an empty (0, 0, C) array when the
            mission has no VideoProducer or no new frame arrived.
        reward: rewards summed since the previous step collected them.
        done: the mission has ended.
        info: the merged observation producers (empty when none was delivered).
        sent: the server queued the commands (otherwise they were not applied).
    """

    frame: np.ndarray
    reward: float
    done: bool
    info: dict[str, Any] = field(default_factory=dict)
    sent: bool = True


class MalmoClient:
    """A MalmoEnv connection to one world server (single agent, role 0).

    Args:
        host: server address.
        port: server port.
        synchronous: request MineRL's synchronous mode (one tick per step).
        seed: ask the (graft) server for this world seed (6th token field).
        timeout: socket timeout in seconds.
        max_backoff: the longest pause between reconnection attempts, in seconds.
        connect_attempts: attempts before ``connect()`` gives up.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = P.DEFAULT_PORT,
        *,
        synchronous: bool = False,
        seed: Optional[int] = None,
        timeout: float = 30.0,
        max_backoff: float = 5.0,
        connect_attempts: int = 10,
    ) -> None:
        self.host, self.port = host, port
        self.synchronous, self.seed = synchronous, seed
        self.timeout, self.max_backoff, self.connect_attempts = (
            timeout,
            max_backoff,
            connect_attempts,
        )
        self.exp_uid = str(uuid.uuid4())
        self.resets = 0
        self.done = True
        self.mission: Optional[Mission] = None
        self._xml = ""
        self._sock: Optional[socket.socket] = None
        self.reconnects = 0

    # ---------------------------------------------------------------- plumbing
    def _open(self) -> socket.socket:
        s = socket.create_connection((self.host, self.port), timeout=self.timeout)
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
            MissionError: the XML cannot be used.
        """
        self.mission = parse_mission(mission_xml)
        self._xml = mission_xml
        self.resets = episode

    def _token(self) -> str:
        return P.Token(self.exp_uid, 0, self.resets, 1, self.synchronous, self.seed).encode()

    def reset(self) -> np.ndarray:
        """End any running episode and start a new one; returns the first frame.

        Reconnects (with backoff) if the server went away.

        Raises:
            MissionRefused: the server refused the mission (reason included).
        """
        if not self._xml:
            raise RuntimeError("call init(mission_xml) before reset()")
        for attempt in range(2):
            try:
                if not self.done and self._sock is not None:
                    self.quit()
                self.resets += 1
                self.connect()
                return self._start()
            except (OSError, ConnectionError, P.ProtocolError):
                self._drop()
                self.reconnects += 1
                if attempt == 1:
                    raise
        raise AssertionError("unreachable")

    def _start(self) -> np.ndarray:
        xml = P.mission_init_xml(self._xml, self.exp_uid)
        sock = self._call(xml.encode(), self._token().encode())
        ok = P.unpack_int(P.recv(sock))
        reason = P.recv(sock).decode("utf-8", "replace")
        if ok != 1:
            raise MissionRefused(reason or "server replied 0 to MissionInit")
        self.done = False
        frame, self.done = self.peek()
        return frame

    def _frame(self, data: bytes) -> np.ndarray:
        m = self.mission
        c = m.channels if m is not None else 3
        if not data or m is None or not m.has_video:
            return np.zeros((0, 0, c), dtype=np.uint8)
        # Malmo sends rows bottom-up (OpenGL order); return them top-down.
        return np.frombuffer(data, dtype=np.uint8).reshape(m.height, m.width, c)[::-1]

    def peek(self) -> tuple[np.ndarray, bool]:
        """The latest frame without acting or consuming it; (frame, done)."""
        sock = self._call(b"<Peek/>")
        data = P.recv(sock)
        done = P.recv(sock) == b"\x01"
        return self._frame(data), done

    def step(self, commands: str | Sequence[str] = "", *, with_info: bool = True) -> StepResult:
        """Send commands (one string, newline-joined, or a sequence) and get the reply.

        Retries (as malmoenv does) while the server reports the commands were not sent.
        """
        text = commands if isinstance(commands, str) else "\n".join(commands)
        opts = 2 if with_info else 3
        msg = P.step_message(text, opts)
        for _ in range(1000):
            sock = self._call(msg)
            data = P.recv(sock)
            reward, done, sent = P.unpack_step_record(P.recv(sock))
            info_text = P.recv(sock).decode("utf-8") if with_info else ""
            self.done = done
            if sent or done:
                info = json.loads(info_text) if info_text else {}
                return StepResult(self._frame(data), reward, done, info, sent)
            time.sleep(0.01)
        raise TimeoutError("server never accepted the step")

    def quit(self) -> None:
        """Ask the server to end the episode and wait until it has."""
        for _ in range(200):
            sock = self._call(b"<Quit/>")
            if P.unpack_int(P.recv(sock)) != 0:
                self.done = True
                return
            time.sleep(0.02)

    def status(self) -> dict[str, Any]:
        """The server's ``<Status/>`` JSON."""
        s = self._open()
        try:
            P.send(s, b"<Status/>")
            return json.loads(P.recv(s).decode("utf-8") or "{}")
        finally:
            s.close()

    def close(self) -> None:
        """Release the token (``<Close>``) on a fresh connection and disconnect."""
        try:
            s = self._open()
            try:
                key = f"{self.exp_uid}:0:{self.resets}"
                P.send(s, f"<Close>{key}</Close>".encode())
                P.recv(s)
            finally:
                s.close()
        except OSError:
            pass
        self._drop()
        self.done = True
