"""Starting a mission on one simulated instance, as Malmo's ``<MissionInit>`` does: the
checks a mission passes first, role 0's world and session, the other roles joining it
through ``<Find>``, and the turn tokens that say which roles have taken their turn.

A role 0 mission builds its ``World`` (outside the instance's lock: terrain takes a
while), registers its ``session.Session`` under the server's port and puts every role's
token up for ``<Find>``; it starts once the other roles took their previous reset's
tokens (Malmo's ``areAllTokensConsumed``). A role > 0 joins the session registered on
its ``MinecraftServerConnection`` port, in role 0's world.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Optional

from minecraft.malmo import protocol as P
from minecraft.malmo.mission import Mission, MissionError, parse_mission
from minecraft.malmo.roles import RoleMission, role_mission
from minecraft.sim import session as S
from minecraft.sim import support
from minecraft.sim.instance import Instance
from minecraft.sim.limits import Limits
from minecraft.sim.timing import Timing
from minecraft.sim.world import World

log = logging.getLogger("graft.minecraft.server")


class MissionStarter:
    """Starts and joins missions on one instance, for its server.

    Args:
        inst: the server's instance.
        seed: base world seed; episode ``reset`` r uses a seed derived from (seed, r)
            unless the mission or the token names one.
        timing: how long a start waits for the other roles' tokens (``wait_s``).
        limits: what one mission may cost (checked before anything is built).
        diamond_keep: the fraction of diamond veins a default world keeps unless the
            mission's generatorOptions say.
    """

    def __init__(
        self, inst: Instance, *, seed: int, timing: Timing, limits: Limits,
        diamond_keep: float = 1.0,
    ) -> None:  # fmt: skip
        self.inst, self.seed, self.timing, self.limits = inst, seed, timing, limits
        self.diamond_keep = diamond_keep
        self.port = 0  # the server's port once it is bound (what <Find> answers)
        self.session: Optional[S.Session] = None

    def close(self) -> None:
        """Unregister the session this instance hosts, if any."""
        if self.session is not None:
            S.unregister(self.session)

    def start(self, cid: int, token: P.Token, xml: str) -> tuple[bool, str]:
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
        if mission.diamond_keep is None:
            mission = dataclasses.replace(mission, diamond_keep=self.diamond_keep)
        if token.role == 0:
            return self._init_role0(cid, token, role, mission, also)
        return self._join(cid, token, role, mission)

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
        if self.session is not None:
            S.unregister(self.session)
        self.session = session
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

    def find(self, key: str) -> int:
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


def _inside(world: World, placement: tuple[float, ...]) -> bool:
    """The point lies within the world's block box."""
    sx, sy, sz = world.blocks.shape
    x, _, z = placement[:3]
    return world.x0 <= x < world.x0 + sx and world.z0 <= z < world.z0 + sz
