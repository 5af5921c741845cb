"""Multi-agent missions across simulated Minecraft instances in one process.

In Malmo each agent has its own Minecraft. Role 0's hosts the mission (its "integrated
server"); a role > 0 asks role 0's MalmoEnv service ``<Find>`` for that server's port
and joins with a MissionInit carrying ``MinecraftServerConnection``. The mission starts
(Malmo's "starting pistol") when every agent has joined and loaded. With
``TurnBasedCommands`` the server hands a single-use turn key to one agent at a time, in
``requestedPosition`` order; a command carrying the key uses the turn and the next agent
gets a fresh key.

Here a ``Session`` is that integrated server, registered under role 0's port; the other
instances find it in this process's registry. Each role plays ``malmo.roles.role_mission``,
the mission with only its own AgentSection, in role 0's world: a role > 0 builds its
``World`` on the host's (``World(share=...)``), so the agents see and change the same
blocks, items and animals and see each other; they share the turn schedule and the
mission's end. Each agent's Minecraft ticks on its own clock at the mission's rate.
"""

from __future__ import annotations

import random
import threading
from typing import Optional

from minecraft.sim.world import World

_KEY_LETTERS = "abcdefghijklmnopqrstuvwxyz"


class Session:
    """A multi-agent mission hosted by role 0's instance.

    Args:
        port: role 0's port (what ``<Find>`` answers; other roles join through it).
        exp_uid: the experiment id of the tokens.
        reset: the reset count of the tokens.
        agent_count: agents in the mission.
        world: role 0's world, which the other roles join.
    """

    def __init__(self, port: int, exp_uid: str, reset: int, agent_count: int, world: World) -> None:
        self.port, self.exp_uid, self.reset = port, exp_uid, reset
        self.agent_count, self.world = agent_count, world
        self._lock = threading.Lock()
        self._joined: set[int] = {0}
        self._loaded: set[int] = set()
        self._positions: dict[int, Optional[int]] = {}
        self._schedule: list[int] = []
        self._turn = -1  # index into the schedule of the agent whose turn it is
        self._key = ""
        self._numbers: dict[int, int] = {}
        self._rng = random.Random(f"{exp_uid}:{reset}")
        self.end_reason: Optional[str] = None

    def join(self, role: int, turn_position: Optional[int]) -> None:
        """Record that ``role`` joined (role 0 joins when it creates the session)."""
        with self._lock:
            self._joined.add(role)
            self._positions[role] = turn_position

    def loaded(self, role: int) -> bool:
        """``role`` finished loading; True once every agent has (the pistol fires and the
        turn schedule starts)."""
        with self._lock:
            self._loaded.add(role)
            go = len(self._loaded) >= self.agent_count
            if go and self._turn < 0 and not self._schedule:
                self._start_turns()
            return go

    def _start_turns(self) -> None:
        # Malmo: well-specified positions in order, then the others.
        roles = [r for r, p in self._positions.items() if p is not None]
        self._schedule = sorted(roles, key=lambda r: (self._positions[r], r))
        if self._schedule:
            self._give_turn(0)

    def _give_turn(self, index: int) -> None:
        self._turn = index % len(self._schedule)
        role = self._schedule[self._turn]
        self._key = "".join(self._rng.choice(_KEY_LETTERS) for _ in range(5))
        self._numbers[role] = self._numbers.get(role, 0) + 1

    def turn_of(self, role: int) -> Optional[tuple[int, str]]:
        """(turn_number, turn_key) while it is ``role``'s turn, else None."""
        with self._lock:
            if self._schedule and self._schedule[self._turn] == role:
                return self._numbers[role], self._key
            return None

    def use_turn(self, role: int, key: str) -> bool:
        """A command with ``key`` reached ``role``'s world: True (and the next agent gets
        the turn) when the key is the current one and it is ``role``'s turn."""
        with self._lock:
            if not self._schedule or self._schedule[self._turn] != role or key != self._key:
                return False
            self._give_turn(self._turn + 1)
            return True

    def end(self, reason: str) -> None:
        """The mission ended for one agent: it ends for all."""
        with self._lock:
            if self.end_reason is None:
                self.end_reason = reason


_REGISTRY: dict[int, Session] = {}
_REGISTRY_LOCK = threading.Lock()


def register(session: Session) -> None:
    """Make ``session`` findable under its port (replacing an older one there)."""
    with _REGISTRY_LOCK:
        _REGISTRY[session.port] = session


def unregister(session: Session) -> None:
    """Forget ``session`` (if it is still the one registered under its port)."""
    with _REGISTRY_LOCK:
        if _REGISTRY.get(session.port) is session:
            del _REGISTRY[session.port]


def lookup(port: int) -> Optional[Session]:
    """The session hosted on ``port`` in this process, if any."""
    with _REGISTRY_LOCK:
        return _REGISTRY.get(port)
