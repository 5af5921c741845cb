"""The simulated world server: one Minecraft instance speaking MalmoEnv over TCP.

By default it behaves like a real Malmo client started with ``launchClient.sh -env``
(``timing.py``): MissionInit answered 0 while busy, a loading delay with empty frames,
frames paced at their own rate, empty info between ticks, no queued commands without a
VideoProducer. ``Timing(ideal=True)`` (``--ideal``) keeps graft's convenient pacing.

It speaks Malmo's dialect to a 4-field token and MineRL's (``<StepClient>`` and
``<StepServer>``, synchronous) to a token with the 5th field; see ``protocol.py``.
Multi-agent missions join across servers of one process (``session.py``).

Protocol errors (bad hello, oversized or unknown messages, the other dialect's steps)
close that one connection with a logged reason, as Malmo does, after an ``error: ...``
message saying why; the server keeps serving. What one client may cost the server
(frame size, grid volume, message size, connections, idle time) is capped by
``limits.Limits``. A mission the simulator raises on ends with an ``error: ...`` reason
(``<Status/>``'s ``end_reason``); the instance runs the next mission as usual.
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
from actors.minecraft.malmo.mission import Mission, MissionError, parse_mission
from actors.minecraft.malmo.roles import RoleMission, role_mission
from actors.minecraft.sim import render, support
from actors.minecraft.sim import session as S
from actors.minecraft.sim.instance import LOADING, RUNNING, Instance
from actors.minecraft.sim.limits import DEFAULT_LIMITS, Limits
from actors.minecraft.sim.timing import REAL, Timing
from actors.minecraft.sim.world import World

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
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = P.DEFAULT_PORT, *, seed: int = 0,
        ms_per_tick: int = 50, timing: Timing = REAL, limits: Limits = DEFAULT_LIMITS,
    ) -> None:  # fmt: skip
        if ms_per_tick <= 0:
            raise ValueError(f"ms_per_tick must be positive, got {ms_per_tick}")
        self.host, self.seed, self.default_ms, self.timing = host, seed, ms_per_tick, timing
        self.limits = limits
        self._requested_port = port
        self.port = 0
        self.inst = Instance(timing, ms_per_tick)
        self._stopped = threading.Event()
        self._listener: Optional[socket.socket] = None
        self._conns: dict[int, socket.socket] = {}
        self._next_conn = 0
        self._session: Optional[S.Session] = None
        self.protocol_errors = 0
        self.busy_replies = 0
        self.refused_connections = 0

    # ------------------------------------------------------------- lifecycle
    def start(self) -> int:
        """Bind, listen and start the accept and tick threads; returns the port."""
        render.warm_up()
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self._requested_port))
        s.listen(64)
        self._listener = s
        self.port = s.getsockname()[1]
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
        if self._session is not None:
            S.unregister(self._session)
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
            P.send(conn, P.pack_int(self._find(P.tag_body(msg, "Find"))))
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
                "connections": len(self._conns),
                "refused_connections": self.refused_connections,
            }

    # ------------------------------------------------------------ mission init
    def _mission_init(self, cid: int, conn: socket.socket, xml: str) -> None:
        token_text = self._recv(conn).decode("utf-8", "replace")
        try:
            token = P.Token.parse(token_text)
        except (P.ProtocolError, ValueError) as e:
            self._reply_init(conn, False, f"error: {e}", minerl=len(token_text.split(":")) > 4)
            return
        try:
            ok, reason = self._start_mission(cid, token, xml)
            if not ok:
                self.busy_replies += 1
        except MissionError as e:
            log.warning("refusing mission: %s", e)
            ok, reason = False, f"error: {e}"
        except Exception as e:  # the simulator failed on this mission: refuse it alone
            log.error("refusing mission: the simulator failed: %s", e, exc_info=e)
            ok, reason = False, f"error: the simulator failed: {type(e).__name__}: {e}"
        self._reply_init(conn, ok, reason, minerl=token.minerl)

    def _start_mission(self, cid: int, token: P.Token, xml: str) -> tuple[bool, str]:
        """Check the mission, then start it or join it: (ok, the busy reason).

        Raises:
            MissionError: the mission cannot be used (the reply names why).
        """
        role = role_mission(xml, token.role)
        parse_mission(xml, role=token.role)  # Malmo's schema rules on the whole MissionInit
        mission = parse_mission(role.xml)
        self.limits.check(mission)  # before anything is built or drawn
        for warning in support.check(mission):  # refuses what the simulator lacks
            log.warning("mission approximated: %s", warning)
        if token.minerl and not token.synchronous:
            raise MissionError("MineRL's asynchronous mode answers no steps; use synchronous")
        if token.agent_count != role.agent_count:
            raise MissionError(
                f"the token says {token.agent_count} agent(s), the mission has "
                f"{role.agent_count} AgentSection(s)"
            )
        if token.role > 0 and role.server_port == 0:
            raise MissionError(f"role {token.role} needs a MinecraftServerConnection")
        # Role 0's world must hold every agent's start.
        also = tuple(
            p[:3]
            for k in range(1, role.agent_count if token.role == 0 else 1)
            if (p := parse_mission(role_mission(xml, k).xml).placement) is not None
        )
        if token.seed is not None:
            mission = dataclasses.replace(mission, seed=token.seed)
        if token.role == 0:
            return self._init_role0(cid, token, role, mission, also)
        return self._join(cid, token, role, mission)

    @staticmethod
    def _reply_init(conn: socket.socket, ok: bool, reason: str, *, minerl: bool) -> None:
        # Malmo replies ok and an empty turn key (graft puts a refusal's reason there);
        # MineRL replies ok alone.
        if minerl:
            P.send(conn, P.pack_int(1 if ok else 0))
        else:
            P.send(conn, P.pack_int(1 if ok else 0), (reason if not ok else "").encode())

    def _free(self) -> Optional[str]:
        """None when the instance may start a mission, else the busy reason."""
        with self.inst.cond:
            return self.inst.claim(time.monotonic())

    def _init_role0(
        self, cid: int, token: P.Token, role: RoleMission, mission: Mission,
        also: tuple[tuple[float, float, float], ...],
    ) -> tuple[bool, str]:  # fmt: skip
        inst = self.inst
        with inst.cond:
            inst.tokens.pop(f"{token.exp_uid}:0:{token.reset - 1}", None)
            pre_started = token.key in inst.tokens
        reason: Optional[str] = None
        if not pre_started:
            reason = self._free()
            if reason is None:
                seed = (self.seed * 1_000_003 + token.reset) & 0x7FFFFFFF
                # Built outside the lock: terrain takes a while.
                world = World(mission, seed, also=also)
                session = S.Session(self.port, token.exp_uid, token.reset, role.agent_count,
                                    world)  # fmt: skip
                session.join(0, role.turn_position)
                with inst.cond:
                    reason = inst.claim(time.monotonic())
                    if reason is None:
                        self._launch(cid, token, role, world, session)
        with inst.cond:
            if reason is None and not self._consumed(token):
                inst.cond.wait(self.timing.wait_s)
                if not self._consumed(token):
                    reason = "busy: the other agents have not taken their previous turn tokens"
        return reason is None, reason or ""

    def _launch(
        self, cid: int, token: P.Token, role: RoleMission, world: World, session: S.Session
    ) -> None:
        inst = self.inst
        if self._session is not None:
            S.unregister(self._session)
        self._session = session
        S.register(session)
        inst.start(
            world, owner=cid, sync=bool(token.synchronous), minerl=token.minerl,
            session=session, role=0, turn_handlers=role.turn_handlers, token=token.key,
        )  # fmt: skip
        # Malmo's addTokens once the integrated server is up: every role can Find it.
        inst.tokens[token.key] = self.port
        for i in range(1, role.agent_count):
            inst.tokens[f"{token.exp_uid}:{i}:{token.reset}"] = self.port

    def _consumed(self, token: P.Token) -> bool:
        """Malmo's areAllTokensConsumed: the other roles took their previous tokens."""
        prev = token.reset - 1
        return all(
            f"{token.exp_uid}:{i}:{prev}" not in self.inst.tokens
            for i in range(1, token.agent_count)
        )

    def _join(
        self, cid: int, token: P.Token, role: RoleMission, mission: Mission
    ) -> tuple[bool, str]:
        session = S.lookup(role.server_port)
        if session is None or (session.exp_uid, session.reset) != (token.exp_uid, token.reset):
            return (
                False,
                f"busy: no mission {token.exp_uid}:{token.reset} on port {role.server_port}",
            )
        reason = self._free()
        if reason is not None:
            return False, reason
        host = session.world
        if mission.placement is not None and not _inside(host, mission.placement):
            return False, f"error: role {token.role} starts outside role 0's world"
        with host.lock:
            world = World(mission, host.seed, share=host)
        session.join(token.role, role.turn_position)
        with self.inst.cond:
            self.inst.start(
                world, owner=cid, sync=bool(token.synchronous), minerl=token.minerl,
                session=session, role=token.role, turn_handlers=role.turn_handlers,
                token=token.key,
            )  # fmt: skip
        return True, ""

    def _find(self, key: str) -> int:
        """``<Find>``: purge the previous reset's token, then the integrated port for
        ``key`` (waiting up to ``wait_s``), 0 if unknown."""
        inst = self.inst
        try:
            exp, role, reset = key.split(":")[:3]
            prev = f"{exp}:{role}:{int(reset) - 1}"
        except ValueError:
            raise P.ProtocolError(f"malformed <Find> token {key!r}") from None
        with inst.cond:
            inst.tokens.pop(prev, None)
            inst.cond.notify_all()
            if key not in inst.tokens:
                inst.cond.wait_for(lambda: key in inst.tokens, self.timing.wait_s)
            return inst.tokens.get(key, 0)

    # ------------------------------------------------------------------ steps
    def _step(self, conn: socket.socket, msg: str) -> None:
        if self.inst.minerl:
            raise P.ProtocolError(
                "MineRL's server has no <StepN>: send <StepClientN>, <StepServer>"
            )
        options, commands = P.parse_step(msg)
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


def _inside(world: World, placement: tuple[float, ...]) -> bool:
    """The point lies within the world's block box."""
    sx, sy, sz = world.blocks.shape
    x, _, z = placement[:3]
    return world.x0 <= x < world.x0 + sx and world.z0 <= z < world.z0 + sz
