"""The simulated Minecraft world server, speaking MalmoEnv over TCP with Malmo's real-time
semantics.

Asynchronous mode (Malmo's): a ticking thread advances the world every ``MsPerTick`` ms
whether or not the agent acts. Commands that steps deliver between two ticks are queued
and all applied at the next tick. Only the latest frame and observation exist (a step
gets the newest; older ones are skipped) and a step that arrives before a new tick waits
for it, up to 3 s, as Malmo's ``cond.await`` does. Rewards add up until a step collects
them. Synchronous mode (5th token field ``true``, MineRL's fork): the world does not tick
by itself; each step queues its commands and advances exactly one tick.

Protocol errors (bad hello, oversized or unknown messages) close that one connection
with a logged reason, as Malmo does; the server keeps serving.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import socket
import threading
import time
from typing import Optional

from actors.minecraft.malmo import protocol as P
from actors.minecraft.malmo.mission import MissionError, parse_mission
from actors.minecraft.sim import support
from actors.minecraft.sim.observe import info_json
from actors.minecraft.sim.render import render
from actors.minecraft.sim.world import World

log = logging.getLogger("graft.minecraft.server")
WAIT_S = 3.0  # Malmo's COND_WAIT_SECONDS


class WorldServer:
    """One simulated Malmo client ("Minecraft instance") on one port.

    Args:
        host: interface to bind (127.0.0.1 unless told otherwise).
        port: TCP port; 0 picks a free one (see ``port`` after ``start()``).
        seed: base world seed; episode ``reset`` r uses a seed derived from (seed, r)
            unless the mission or the token names one.
        ms_per_tick: tick period when the mission has no ModSettings/MsPerTick.
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = P.DEFAULT_PORT, *, seed: int = 0,
        ms_per_tick: int = 50,
    ) -> None:  # fmt: skip
        if ms_per_tick <= 0:
            raise ValueError(f"ms_per_tick must be positive, got {ms_per_tick}")
        self.host, self.seed, self.default_ms = host, seed, ms_per_tick
        self._requested_port = port
        self.port = 0
        self._cond = threading.Condition()
        self._stopped = threading.Event()
        self._wake = threading.Event()  # new mission or stop: re-plan the tick thread
        self._listener: Optional[socket.socket] = None
        self._conns: dict[int, socket.socket] = {}
        self._next_conn = 0
        self.world: Optional[World] = None
        self._owner = -1
        self._sync = False
        self._ms = ms_per_tick
        self._done = False
        self._quit = False
        self._commands: list[str] = []
        self._delivered = -1
        self._frame: tuple[int, bytes] = (-1, b"")
        self._info: tuple[int, str] = (-1, "")
        self._tokens: dict[str, int] = {}
        self.protocol_errors = 0
        self.missions_started = 0

    # ------------------------------------------------------------- lifecycle
    def start(self) -> int:
        """Bind, listen and start the accept and tick threads; returns the port."""
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self._requested_port))
        s.listen(64)
        self._listener = s
        self.port = s.getsockname()[1]
        threading.Thread(target=self._accept_loop, name="mc-accept", daemon=True).start()
        threading.Thread(target=self._tick_loop, name="mc-tick", daemon=True).start()
        log.info("world server listening on %s:%d", self.host, self.port)
        return self.port

    def serve_forever(self) -> None:
        """Start (if needed) and block until ``stop()``."""
        if self._listener is None:
            self.start()
        self._stopped.wait()

    def stop(self) -> None:
        """Stop serving and close every connection."""
        self._stopped.set()
        self._wake.set()
        if self._listener is not None:
            try:
                # shutdown() wakes the thread blocked in accept(); close() alone does not.
                self._listener.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._listener.close()
        with self._cond:
            for c in list(self._conns.values()):
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                c.close()
            self._cond.notify_all()

    def __enter__(self) -> WorldServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---------------------------------------------------------------- ticking
    def _tick_loop(self) -> None:
        # Sleeps on its own event, not on the condition: steps notify the condition and
        # must not wake this thread (a context switch per synchronous step).
        next_t = time.monotonic()
        while not self._stopped.is_set():
            with self._cond:
                idle = self.world is None or self._done or self._sync
                period = self._ms / 1000.0
            if idle:
                self._wake.wait(0.1)
                self._wake.clear()
                next_t = time.monotonic()
                continue
            now = time.monotonic()
            if now < next_t:
                self._wake.wait(next_t - now)
                self._wake.clear()
                continue
            with self._cond:
                if self.world is not None and not self._done and not self._sync:
                    self._advance()
            # Real time: a late tick is not made up by a burst of ticks.
            next_t = max(next_t + period, now)

    def _advance(self) -> None:
        """One tick under the lock: apply queued commands, tick, publish."""
        w = self.world
        assert w is not None
        if self._quit:
            w.end("quit")
        else:
            cmds, self._commands = self._commands, []
            w.tick(cmds)
        if w.done:
            self._done = True
            log.info("mission ended at tick %d: %s", w.tick_count, w.end_reason)
        self._cond.notify_all()

    # ------------------------------------------------------------ observation
    def _latest_frame(self) -> bytes:
        w = self.world
        if w is None:
            return b""
        if self._frame[0] != w.tick_count:
            m = w.mission
            data = render(w, m.width, m.height, depth=m.want_depth) if m.has_video else b""
            self._frame = (w.tick_count, data)
        return self._frame[1]

    def _latest_info(self) -> str:
        w = self.world
        if w is None:
            return ""
        if self._info[0] != w.tick_count:
            self._info = (w.tick_count, info_json(w))
        return self._info[1]

    def _fresh(self) -> bool:
        return self.world is not None and self.world.tick_count > self._delivered

    # ------------------------------------------------------------ connections
    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stopped.is_set():
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._cond:
                cid = self._next_conn
                self._next_conn += 1
                self._conns[cid] = conn
            threading.Thread(
                target=self._serve_conn, args=(cid, conn), name=f"mc-conn-{cid}", daemon=True
            ).start()

    def _serve_conn(self, cid: int, conn: socket.socket) -> None:
        try:
            hello = P.recv(conn, P.MAX_HELLO)
            if not hello.decode("utf-8", "replace").startswith(P.HELLO_PREFIX + P.VERSION):
                raise P.ProtocolError(f"bad hello {hello[:40]!r}, expected {P.HELLO!r}")
            while not self._stopped.is_set():
                self._dispatch(cid, conn, P.recv(conn).decode("utf-8", "replace"))
        except P.ProtocolError as e:
            self.protocol_errors += 1
            log.warning("closing connection %d: %s", cid, e)
        except (OSError, ConnectionError):
            pass
        finally:
            with self._cond:
                self._conns.pop(cid, None)
                if self._owner == cid and self.world is not None and not self._done:
                    log.info("mission owner disconnected; quitting the mission")
                    self._quit = True
                    if self._sync:
                        self._advance()
            conn.close()

    def _dispatch(self, cid: int, conn: socket.socket, msg: str) -> None:
        if msg.startswith("<Step"):
            self._step(conn, msg)
        elif msg.startswith("<Peek"):
            self._peek(conn)
        elif msg.startswith("<MissionInit"):
            self._mission_init(cid, conn, msg)
        elif msg.startswith("<Quit"):
            with self._cond:
                if not self._done and self.world is not None:
                    self._quit = True
                    if self._sync:
                        self._advance()
                P.send(conn, P.pack_int(1 if self._done else 0))
        elif msg.startswith("<Close"):
            with self._cond:
                self._tokens.pop(P.tag_body(msg, "Close"), None)
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Init"):
            with self._cond:
                self._tokens.clear()
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Find"):
            key = P.tag_body(msg, "Find")
            with self._cond:
                port = self._tokens.get(key, 0)
            P.send(conn, P.pack_int(port))
        elif msg.startswith("<Exit"):
            # Malmo exits the JVM for its launcher to restart; we restart in place.
            with self._cond:
                self._tokens.clear()
                if self.world is not None and not self._done:
                    self.world.end("exit")
                    self._done = True
                self._cond.notify_all()
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Status"):
            P.send(conn, json.dumps(self.status()).encode())
        elif msg.startswith("<Echo"):
            P.send(conn, f"<Echo>{msg}</Echo>".encode())
        else:
            raise P.ProtocolError(f"unknown message {msg[:60]!r}")

    def status(self) -> dict[str, object]:
        """Server state for ``<Status/>`` (Malmo answers ``{}``; this is a superset)."""
        with self._cond:
            w = self.world
            return {
                "version": P.VERSION,
                "mission_running": w is not None and not self._done,
                "synchronous": self._sync,
                "ms_per_tick": self._ms,
                "tick": w.tick_count if w is not None else 0,
                "seed": w.seed if w is not None else self.seed,
                "end_reason": w.end_reason if w is not None else "",
                "ignored_commands": w.ignored_commands if w is not None else 0,
                "protocol_errors": self.protocol_errors,
                "missions_started": self.missions_started,
            }

    def _mission_init(self, cid: int, conn: socket.socket, xml: str) -> None:
        token_text = P.recv(conn).decode("utf-8", "replace")
        try:
            token = P.Token.parse(token_text)
            mission = parse_mission(xml)
            for warning in support.check(mission):  # refuses what the simulator lacks
                log.warning("mission approximated: %s", warning)
            if token.role != 0 or token.agent_count > 1 or mission.agent_count > 1:
                raise MissionError("multi-agent missions are not simulated (role 0 only)")
        except (P.ProtocolError, MissionError) as e:
            log.warning("refusing mission: %s", e)
            # Malmo replies 0 and an empty turn key; the reason rides in the turn key slot.
            P.send(conn, P.pack_int(0), f"error: {e}".encode())
            return
        if token.seed is not None:
            mission = dataclasses.replace(mission, seed=token.seed)
        seed = (self.seed * 1_000_003 + token.reset) & 0x7FFFFFFF
        world = World(mission, seed)
        with self._cond:
            if self.world is not None and not self._done:
                self.world.end("replaced by a new mission")
            self.world = world
            self._owner = cid
            self._sync = token.synchronous
            self._ms = mission.ms_per_tick or self.default_ms
            self._done = self._quit = False
            self._commands = []
            self._delivered = -1
            self._frame, self._info = (-1, b""), (-1, "")
            self._tokens[token.key] = self.port
            self.missions_started += 1
            self._cond.notify_all()
        self._wake.set()
        P.send(conn, P.pack_int(1), b"")

    def _peek(self, conn: socket.socket) -> None:
        with self._cond:
            if self.world is None and not self._done:
                self._cond.wait(WAIT_S)
            frame = self._latest_frame()
            done = self._done
        P.send(conn, frame, bytes([1 if done else 0]))

    def _step(self, conn: socket.socket, msg: str) -> None:
        options, commands = P.parse_step(msg)
        with_key, with_info = P.step_flags(options)
        step_key = P.recv(conn, 4096) if with_key else b""
        reward, sent, info, frame = 0.0, False, "", b""
        with self._cond:
            done = self._done
            if self._sync and self.world is not None and not done and not step_key:
                self._commands.extend(commands)
                self._advance()
                sent, fresh = True, True
            else:
                fresh = self._fresh()
                if not fresh and not done:
                    self._cond.wait_for(lambda: self._fresh() or self._done, WAIT_S)
                    fresh = self._fresh()
                if not done and fresh and not step_key:
                    self._commands.extend(commands)
                    sent = True
            done = self._done
            if done or (fresh and sent):
                w = self.world
                if w is not None:
                    reward, w.pending_reward = w.pending_reward, 0.0
                    if fresh:
                        frame = self._latest_frame()
                        if with_info:
                            info = self._latest_info()
                        self._delivered = w.tick_count
            elif fresh:
                frame = self._latest_frame()
        out = [frame, P.pack_step_record(reward, done, sent)]
        if with_info:
            out.append(info.encode())
        if with_key:
            out.append(b"")  # turn-based missions are not simulated: no turn key
        P.send(conn, *out)
