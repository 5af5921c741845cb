"""The simulated world server: one Minecraft instance speaking MalmoEnv over TCP.

By default it behaves like a real Malmo client started with ``launchClient.sh -env``
(``timing.py``): MissionInit answered 0 while busy, a loading delay with empty frames,
frames paced at their own rate, empty info between ticks, no queued commands without a
VideoProducer. ``Timing(ideal=True)`` (``--ideal``) keeps graft's convenient pacing.

It speaks Malmo's dialect to a 4-field token and MineRL's (``<StepClient>`` and
``<StepServer>``, synchronous) to a token with the 5th field; see ``protocol.py``.
Starting and joining missions is ``mission_start.py``; multi-agent missions join across
servers of one process (``session.py``).

Protocol errors (bad hello, oversized or unknown messages, the other dialect's steps)
close that one connection with a logged reason, as Malmo does, after an ``error: ...``
message saying why; the server keeps serving. What one client may cost the server
(frame size, grid volume, message size, connections, idle time) is capped by
``limits.Limits``. MissionInit is answered as Malmo does (ok and an empty turn key;
0 while busy, the reason in the log and ``<Status/>``), except that a mission this
server will never run (invalid, unsupported, over a limit) gets one ``error: ...``
message in place of the ok int. A mission the simulator raises on ends with an ``error: ...`` reason
(``<Status/>``'s ``end_reason``); the instance runs the next mission as usual.
"""

from __future__ import annotations

import json
import logging
import socket
import threading
import time
from typing import Optional

from minecraft.malmo import protocol as P
from minecraft.malmo.mission import MissionError
from minecraft.sim import render
from minecraft.sim.instance import LOADING, RUNNING, Instance
from minecraft.sim.limits import DEFAULT_LIMITS, Limits
from minecraft.sim.mission_start import MissionStarter
from minecraft.sim.timing import IDEAL, REAL, Timing
from minecraft.sim.worldgen import check_keep

log = logging.getLogger("graft.minecraft.server")


class WorldServer:
    """One simulated Malmo client ("Minecraft instance") on one port.

    Args:
        host: interface to bind (127.0.0.1 unless told otherwise).
        port: TCP port; 0 picks a free one (see ``port`` after ``start()``).
        seed: base world seed; episode ``reset`` r uses a seed derived from (seed, r)
            unless the mission or the token names one.
        ms_per_tick: tick period when the mission has no ModSettings/MsPerTick.
        timing: real Malmo's pacing (the default) or ``Timing(ideal=True)``.
        limits: what one client may cost the server (frames, grids, messages,
            connections, idle time).
        diamond_keep: the fraction of diamond veins (6-connected groups of ore) a
            default world keeps, drawn per vein from the world's seed; the others are
            stone. A mission's generatorOptions ``diamondKeep`` overrides it.
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = P.DEFAULT_PORT, *, seed: int = 0,
        ms_per_tick: int = 50, timing: Timing = REAL, limits: Limits = DEFAULT_LIMITS,
        diamond_keep: float = 1.0,
    ) -> None:  # fmt: skip
        if ms_per_tick <= 0:
            raise ValueError(f"ms_per_tick must be positive, got {ms_per_tick}")
        check_keep(diamond_keep)
        self.host, self.seed, self.default_ms, self.timing = host, seed, ms_per_tick, timing
        self.limits = limits
        self._requested_port = port
        self.port = 0
        self.inst = Instance(timing, ms_per_tick)
        self._stopped = threading.Event()
        self._listener: Optional[socket.socket] = None
        self._conns: dict[int, socket.socket] = {}
        self._next_conn = 0
        self._missions = MissionStarter(
            self.inst, seed=seed, timing=timing, limits=limits, diamond_keep=diamond_keep
        )
        self.protocol_errors = 0
        self.busy_replies = 0
        self.refused_connections = 0
        self.last_refusal = ""  # why the last MissionInit was answered 0 or refused

    # ------------------------------------------------------------- lifecycle
    def start(self) -> int:
        """Bind, listen and start the accept and tick threads; returns the port."""
        render.warm_up()
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self._requested_port))
        s.listen(64)
        self._listener = s
        self.port = self._missions.port = s.getsockname()[1]
        threading.Thread(target=self._accept_loop, name="mc-accept", daemon=True).start()
        threading.Thread(target=self._tick_loop, name="mc-tick", daemon=True).start()
        log.info("world server (%s timing) on %s:%d", self.timing.mode, self.host, self.port)
        return self.port

    def serve_forever(self) -> None:
        """Start (if needed) and block until ``stop()``."""
        if self._listener is None:
            self.start()
        self._stopped.wait()

    def stop(self) -> None:
        """Stop serving and close every connection."""
        self._stopped.set()
        self.inst.wake.set()
        self._missions.close()
        if self._listener is not None:
            try:
                # shutdown() wakes the thread blocked in accept(); close() alone does not.
                self._listener.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self._listener.close()
        with self.inst.cond:
            for c in list(self._conns.values()):
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                c.close()
            self.inst.cond.notify_all()

    def __enter__(self) -> WorldServer:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---------------------------------------------------------------- ticking
    def _tick_loop(self) -> None:
        # Sleeps on its own event, not on the condition: steps notify the condition and
        # must not wake this thread (a context switch per synchronous step).
        inst = self.inst
        generation, next_t = -1, 0.0
        while not self._stopped.is_set():
            with inst.cond:
                inst.poll_phase(time.monotonic())
                due = inst.tick_due()
                if inst.generation != generation:
                    # A new mission keeps none of the previous one's tick deadline.
                    generation, next_t = inst.generation, 0.0
                phase, period, t0 = inst.phase, inst.ms / 1000.0, inst.run_t0
            if due is None or phase == LOADING:
                inst.wake.wait(0.1 if due is None else due)
                inst.wake.clear()
                continue
            now = time.monotonic()
            if next_t == 0.0:
                next_t = t0 + period  # the first tick one period after the run starts
            if now < next_t:
                inst.wake.wait(next_t - now)
                inst.wake.clear()
                continue
            with inst.cond:
                if inst.generation == generation and inst.phase == RUNNING and not inst.sync:
                    inst.advance()  # a mission that fails in its tick ends; this thread goes on
            # Real time: a late tick is not made up by a burst of ticks.
            next_t = max(next_t + period, now)

    # ------------------------------------------------------------ connections
    def _accept_loop(self) -> None:
        assert self._listener is not None
        while not self._stopped.is_set():
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self.inst.cond:
                full = len(self._conns) >= self.limits.max_connections
                if not full:
                    cid = self._next_conn
                    self._next_conn += 1
                    self._conns[cid] = conn
            if full:
                self.refused_connections += 1
                log.warning("refusing a connection: %d open", self.limits.max_connections)
                self._refuse(
                    conn,
                    f"the server has {self.limits.max_connections} connections open, its "
                    "limit (--max-connections)",
                )
                continue
            conn.settimeout(self.limits.idle_timeout_s)
            threading.Thread(
                target=self._serve_conn, args=(cid, conn), name=f"mc-conn-{cid}", daemon=True
            ).start()

    @staticmethod
    def _refuse(conn: socket.socket, reason: str) -> None:
        """Send ``error: reason`` (best effort; the peer may not be reading) and close."""
        try:
            conn.settimeout(1.0)
            P.send(conn, f"error: {reason}".encode())
            conn.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        conn.close()

    def _recv(self, conn: socket.socket) -> bytes:
        """One request, read as its bytes arrive, at most ``max_message_bytes``."""
        try:
            return P.recv(conn, self.limits.max_message_bytes)
        except P.ProtocolError as e:
            raise P.ProtocolError(f"{e} (--max-message-bytes)") from None

    def _serve_conn(self, cid: int, conn: socket.socket) -> None:
        error = ""
        try:
            hello = P.recv(conn, P.MAX_HELLO)
            if not hello.decode("utf-8", "replace").startswith(P.HELLO_PREFIX + P.VERSION):
                raise P.ProtocolError(f"bad hello {hello[:40]!r}, expected {P.HELLO!r}")
            while not self._stopped.is_set():
                self._dispatch(cid, conn, self._recv(conn).decode("utf-8", "replace"))
        except P.ProtocolError as e:
            self.protocol_errors += 1
            log.warning("closing connection %d: %s", cid, e)
            error = str(e)
        except TimeoutError:
            log.info("closing connection %d: idle", cid)
            error = f"idle for {self.limits.idle_timeout_s:g} s (--idle-timeout-s); closing"
        except (OSError, ConnectionError):
            pass
        except Exception as e:  # a simulator failure ends this connection's mission only
            with self.inst.cond:
                if self.inst.owner == cid:
                    self.inst.fail(e)
                else:
                    log.error("closing connection %d: %s", cid, e, exc_info=e)
            error = f"the simulator failed: {type(e).__name__}: {e}"
        finally:
            with self.inst.cond:
                self._conns.pop(cid, None)
                if self.inst.owner == cid and self.inst.phase in (LOADING, RUNNING):
                    log.info("mission owner disconnected; quitting the mission")
                    self.inst.request_quit()
            if error:
                self._refuse(conn, error)
            conn.close()

    def _dispatch(self, cid: int, conn: socket.socket, msg: str) -> None:
        inst = self.inst
        if msg.startswith("<StepClient"):
            self._step_client(conn, msg)
        elif msg.startswith("<StepServer"):
            if not inst.minerl:
                raise P.ProtocolError("<StepServer> is MineRL's; the mission has a 4-field token")
            # MineRL's server tick; the world already advanced in <StepClient>. No reply.
        elif msg.startswith("<Step"):
            self._step(conn, msg)
        elif msg.startswith("<Peek"):
            with inst.cond:
                frame, info, done = inst.peek()
            done_b = bytes([1 if done else 0])
            P.send(conn, *([frame, info.encode(), done_b] if inst.minerl else [frame, done_b]))
        elif msg.startswith("<MissionInit"):
            self._mission_init(cid, conn, msg)
        elif msg.startswith("<Quit"):
            with inst.cond:
                done = inst.request_quit()
            P.send(conn, P.pack_int(1 if done else 0))
        elif msg.startswith("<Close"):
            with inst.cond:
                inst.tokens.pop(P.tag_body(msg, "Close"), None)
                inst.cond.notify_all()
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Init"):
            with inst.cond:
                inst.tokens.clear()
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Find"):
            P.send(conn, P.pack_int(self._missions.find(P.tag_body(msg, "Find"))))
        elif msg.startswith("<Exit"):
            # Malmo exits the JVM for its launcher to restart; we restart in place.
            with inst.cond:
                inst.tokens.clear()
                inst.end_now("exit")
            P.send(conn, P.pack_int(1))
        elif msg.startswith("<Status"):
            P.send(conn, json.dumps(self.status()).encode())
        elif msg.startswith("<Echo"):
            P.send(conn, f"<Echo>{msg}</Echo>".encode())
        else:
            raise P.ProtocolError(f"unknown message {msg[:60]!r}")

    def status(self) -> dict[str, object]:
        """Server state for ``<Status/>`` (Malmo answers ``{}``; this is a superset)."""
        inst = self.inst
        with inst.cond:
            w = inst.world
            return {
                "version": P.VERSION,
                "timing": self.timing.mode,
                "phase": inst.phase,
                "mission_running": inst.phase in (LOADING, RUNNING),
                "synchronous": inst.sync,
                "ms_per_tick": inst.ms,
                "tick": w.tick_count if w is not None else 0,
                "seed": w.seed if w is not None else self.seed,
                "end_reason": w.end_reason if w is not None else "",
                "ignored_commands": w.ignored_commands if w is not None else 0,
                "protocol_errors": self.protocol_errors,
                "missions_started": inst.missions_started,
                "missions_failed": inst.missions_failed,
                "busy_replies": self.busy_replies,
                "last_refusal": self.last_refusal,
                "connections": len(self._conns),
                "refused_connections": self.refused_connections,
            }

    # ------------------------------------------------------------ mission init
    def _mission_init(self, cid: int, conn: socket.socket, xml: str) -> None:
        token_text = self._recv(conn).decode("utf-8", "replace")
        minerl = len(token_text.split(":")) > 4  # MineRL's 5th field: ok alone
        try:
            token = P.Token.parse(token_text)
            ok, reason = self._missions.start(cid, token, xml)
        except (P.ProtocolError, ValueError, MissionError) as e:
            ok, reason = False, f"error: {e}"
        except Exception as e:  # the simulator failed on this mission: refuse it alone
            log.error("refusing mission: the simulator failed: %s", e, exc_info=e)
            ok, reason = False, f"error: the simulator failed: {type(e).__name__}: {e}"
        if ok:
            # Malmo: ok and an empty turn key (its initial key is a TODO); MineRL: ok alone.
            P.send(conn, P.pack_int(1), *([] if minerl else [b""]))
            return
        self.last_refusal = reason
        if reason.startswith("error: "):
            # A mission this server will never run. Malmo answers 0 as if busy, and
            # malmoenv retries that for ever; one error message in place of the ok int
            # makes malmoenv's init raise and names the reason to graft's client.
            log.warning("refusing mission: %s", reason)
            P.send(conn, reason.encode())
            return
        # Busy: Malmo's reply exactly (0 and an empty turn key); the reason is logged and
        # in <Status/>.
        self.busy_replies += 1
        log.info("answering MissionInit 0: %s", reason)
        P.send(conn, P.pack_int(0), *([] if minerl else [b""]))

    # ------------------------------------------------------------------ steps
    def _step(self, conn: socket.socket, msg: str) -> None:
        if self.inst.minerl:
            raise P.ProtocolError(
                "MineRL's server has no <StepN>: send <StepClientN>, <StepServer>"
            )
        options, commands = P.parse_step(msg)
        if P.step_is_cut(msg):
            log.warning("%r has no space before its last '>': as Malmo does, its commands "
                        "lose their last character", msg[-40:])  # fmt: skip
        with_key, with_info = P.step_flags(options)
        step_key = P.recv(conn, 4096).decode("utf-8", "replace") if with_key else ""
        with self.inst.cond:
            r = self.inst.step(commands, with_info=with_info, step_key=step_key)
        out = [r.frame, P.pack_step_record(r.reward, r.done, r.sent)]
        if with_info:
            out.append(r.info.encode())
        if with_key:
            out.append(r.turn_key.encode())
        P.send(conn, *out)

    def _step_client(self, conn: socket.socket, msg: str) -> None:
        if not self.inst.minerl:
            raise P.ProtocolError("<StepClient> is MineRL's; the mission has a 4-field token")
        options, commands = P.parse_step(msg)
        with_info = options in (0, 2)
        with self.inst.cond:
            r = self.inst.step_sync(commands, with_info=with_info)
        out = [r.frame, P.pack_step_record(r.reward, r.done, r.sent)]
        if with_info:
            out.append(r.info.encode())
        P.send(conn, *out)


def ideal_world_server(
    host: str = "127.0.0.1", port: int = P.DEFAULT_PORT, *, seed: int = 0,
    ms_per_tick: int = 50, limits: Limits = DEFAULT_LIMITS,
) -> WorldServer:  # fmt: skip
    """A world server with graft's ideal pacing (``--ideal``: no loading or ending seconds),
    for an environment's ``world_server`` import string
    (``minecraft.sim.server:ideal_world_server``); otherwise `WorldServer`'s."""
    return WorldServer(host, port, seed=seed, ms_per_tick=ms_per_tick, timing=IDEAL, limits=limits)
