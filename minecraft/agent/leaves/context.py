"""The blackboard context the tree's leaves share, the per-tick command sheet they write,
and the leaf base class.

Each tick the runner puts the new ``Percept`` in ``ctx.percept``, clears the one-shot
commands, ticks the tree, and sends ``ctx.commands.render()`` as one MalmoEnv step.
Continuous states (move, strafe, turn, pitch, jump, attack, use) are sent in full every
tick, so a leaf that stops writing them leaves the agent still.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any, Optional

import py_trees
from py_trees.common import Access

from minecraft.agent.astar import Planner
from minecraft.agent.leaves.percept import Cell, Percept

CONTEXT_KEY = "ctx"
_namespaces = itertools.count()


def new_namespace() -> str:
    """A blackboard namespace unique in this process (the blackboard is global)."""
    return f"/minecraft_{next(_namespaces)}"


def share(ctx: Context, *, name: str, namespace: Optional[str] = None) -> str:
    """Puts ``ctx`` on the blackboard where its tree's leaves read it, under ``namespace``
    (a fresh one by default), and records the namespace in ``ctx.namespace`` for
    `forget_namespace`. Returns the namespace."""
    ns = namespace or new_namespace()
    bb = py_trees.blackboard.Client(name=name, namespace=ns)
    bb.register_key(CONTEXT_KEY, access=Access.WRITE)
    bb.set(CONTEXT_KEY, ctx)
    ctx.namespace = ns
    return ns


def forget_namespace(namespace: str) -> None:
    """Takes a finished tree's namespace off py_trees' process-wide blackboard: its keys'
    values and metadata, and the clients (the tree's leaves) registered to them.

    The blackboard is a class-level store that keeps whatever a tree put there for the
    life of the process: without this, every environment or episode that builds a tree
    leaves its ``Context`` (percept, planner and plan cache) behind. The tree must not
    tick again afterwards.

    Raises:
        ValueError: no namespace (a context never shared): that would forget every tree's.
    """
    prefix = namespace.rstrip("/") + "/"
    if prefix == "/":
        raise ValueError(f"not a tree's namespace: {namespace!r}")
    board = py_trees.blackboard.Blackboard
    for key in [k for k in board.metadata if k.startswith(prefix)]:
        meta = board.metadata.pop(key)
        for client in meta.read | meta.write | meta.exclusive:
            board.clients.pop(client, None)
    for key in [k for k in board.storage if k.startswith(prefix)]:
        del board.storage[key]


@dataclass
class Commands:
    """ContinuousMovementCommands states plus one-shot commands for one step.

    ``hold`` is how many ticks the commands stay in force (a slow client sends one step
    every ``hold`` ticks and Malmo keeps continuous commands until the next): the
    controllers (``control.steer``, ``control.aim``) size a turn or a walk to cover the
    error left in that many ticks, not in one.
    """

    move: float = 0.0
    strafe: float = 0.0
    turn: float = 0.0
    pitch: float = 0.0
    jump: bool = False
    attack: bool = False
    use: bool = False
    once: list[str] = field(default_factory=list)
    hold: int = 1

    def still(self) -> None:
        """Stop moving, turning and acting."""
        self.move = self.strafe = self.turn = self.pitch = 0.0
        self.jump = self.attack = self.use = False

    def render(self) -> str:
        """Newline-joined Malmo commands."""
        lines = [
            f"move {self.move:.3f}",
            f"strafe {self.strafe:.3f}",
            f"turn {self.turn:.3f}",
            f"pitch {self.pitch:.3f}",
            f"jump {int(self.jump)}",
            f"attack {int(self.attack)}",
            f"use {int(self.use)}",
        ]
        return "\n".join(lines + self.once)


@dataclass
class Context:
    """What the leaves share through the blackboard.

    Attributes:
        percept: the current observation.
        commands: the command sheet for this tick.
        planner: the A* planner (memoising).
        goals: destination feet cells (world) of the travel sub-tree.
        target: the block a mining leaf works on (world cell).
        plan_step: the next A* step, in world coordinates (kind, cell).
        plan_reached: the last plan ends at a goal.
        stage: a human-readable name of what the tree is doing.
        memory: small per-leaf scratch state (exploration heading, failures...).
        namespace: the blackboard namespace it is shared under (`share`).
    """

    percept: Percept = field(default_factory=lambda: Percept(0.0, 0.0, 0.0))
    commands: Commands = field(default_factory=Commands)
    planner: Planner = field(default_factory=lambda: Planner(max_expansions=3000))
    goals: frozenset[Cell] = frozenset()
    target: Optional[Cell] = None
    plan_step: Optional[tuple[str, Cell]] = None
    plan_reached: bool = False
    stage: str = ""
    memory: dict[str, Any] = field(default_factory=dict)
    namespace: str = ""


class Leaf(py_trees.behaviour.Behaviour):
    """A leaf that reads and writes the shared ``Context`` on the blackboard.

    Subclasses override ``update()`` (and ``initialise()``/``terminate()`` when needed),
    nothing else.
    """

    def __init__(self, name: str, *, namespace: str) -> None:
        """Attach to the tree's blackboard namespace.

        Args:
            name: the name shown in the tree.
            namespace: the tree's blackboard namespace.
        """
        super().__init__(name)
        self.blackboard = self.attach_blackboard_client(name=name, namespace=namespace)
        self.blackboard.register_key(CONTEXT_KEY, access=Access.WRITE)

    @property
    def ctx(self) -> Context:
        """The shared context."""
        return self.blackboard.get(CONTEXT_KEY)  # type: ignore[no-any-return]
