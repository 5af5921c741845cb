"""Malmo's ``BuildBattleDecorator`` and ``RewardForStructureCopying``: the agents copy a
goal structure into a player area; the copy's score is its right blocks less its wrong
ones (air in the copy counts neither way).

As in Java: the goal structure cannot be broken or built on; the world's host scores
the copy at its first tick (the baseline, no reward) and again at each tick after a block
was placed or broken in the copy, reading its record of what was placed there (not the
world: right blocks may be recoloured with ``BlockTypeOnCorrectPlacement``, in the copy
and the goal alike, wrong ones with ``BlockTypeOnIncorrectPlacement``). Each change of
score goes to every agent's ``RewardForStructureCopying``: ``rewardScale`` per point,
plus ``rewardForCompletion`` the first time the copy matches; the agent keeps its share
of ``rewardDistribution`` and gives the others theirs; ``AddQuitProducer`` ends the
mission once the copy is complete.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Optional, Protocol

from minecraft import blocks as B
from minecraft.malmo.decorator_specs import BuildBattleSpec
from minecraft.malmo.mission_rules import StructureCopying

Cell = tuple[int, int, int]


class Site(Protocol):
    """What the build battle reads and changes of the host's world."""

    def get(self, x: int, y: int, z: int) -> int:
        """The block id at a cell."""
        ...

    def set(self, x: int, y: int, z: int, block: int) -> None:
        """Set a block."""
        ...


def _inside(cell: Cell, box: tuple[Cell, Cell]) -> bool:
    lo, hi = box
    return all(a <= v <= b for v, a, b in zip(cell, lo, hi, strict=True))


def volume(box: tuple[Cell, Cell]) -> int:
    """Cells in an inclusive box."""
    lo, hi = box
    return (1 + hi[0] - lo[0]) * (1 + hi[1] - lo[1]) * (1 + hi[2] - lo[2])


class BuildBattle:
    """The decorator's state on the host's world."""

    def __init__(self, spec: BuildBattleSpec) -> None:
        self.spec = spec
        self.delta = tuple(p - g for p, g in zip(spec.player[0], spec.goal[0], strict=True))
        self.source: dict[Cell, int] = {}  # the goal structure, read once
        self.dest: dict[Cell, int] = {}  # the copy as placed (not as recoloured)
        self.right = B.ID[spec.correct] if spec.correct else None
        self.wrong = B.ID[spec.incorrect] if spec.incorrect else None
        self.score = 0
        self.completed = False
        self.valid = True
        self.started = False

    def protects(self, cell: Cell) -> bool:
        """Whether an agent is refused breaking or placing a block at ``cell``."""
        return _inside(cell, self.spec.goal)

    def changed(self, cell: Cell, block: int) -> None:
        """An agent placed ``block`` (AIR: broke one) at ``cell``."""
        if _inside(cell, self.spec.player):
            self.valid = False
            self.dest[cell] = block

    def update(self, world: Site) -> Optional[tuple[int, bool]]:
        """Score the copy when due: (change of score, completed for the first time) when
        the score changed, else None."""
        if not self.started:
            self.started = True
            self._score(world)
            return None
        if self.valid:
            return None
        before, was_complete = self.score, self.completed
        self._score(world)
        if self.score == before:
            return None
        return self.score - before, self.completed and not was_complete

    def _score(self, world: Site) -> None:
        right = wrong = matching = 0
        (x0, y0, z0), (x1, y1, z1) = self.spec.goal
        dx, dy, dz = self.delta
        for x in range(x0, x1 + 1):
            for y in range(y0, y1 + 1):
                for z in range(z0, z1 + 1):
                    g, p = (x, y, z), (x + dx, y + dy, z + dz)
                    src = self.source.setdefault(g, world.get(*g))
                    dst = self.dest.setdefault(p, world.get(*p))
                    dest_air = world.get(*p) == B.AIR
                    if src == dst:
                        right += not dest_air
                        if self.right is not None and world.get(*g) != B.AIR:
                            world.set(*p, self.right)
                            world.set(*g, self.right)
                        matching += 1
                    else:
                        if not dest_air:
                            wrong += 1
                            if self.wrong is not None:
                                world.set(*p, self.wrong)
                        if world.get(*g) != src:
                            world.set(*g, src)  # a goal block marked right goes back
        self.score = right - wrong
        if matching == volume(self.spec.goal):
            self.completed = True
        self.valid = True


class Payee(Protocol):
    """An agent's world, as a reward share reaches it."""

    pending_reward: float
    copying: Copying


class Copying:
    """One agent's ``RewardForStructureCopying`` (inactive when ``spec`` is None).

    Args:
        spec: the handler, or None.
        name: the agent's name (its share in ``rewardDistribution``).
    """

    def __init__(self, spec: Optional[StructureCopying], name: str) -> None:
        self.spec, self.name = spec, name
        self.owed = 0.0
        self.complete = False

    def scored(self, change: int, completed: bool) -> None:
        """The build battle's message: the score changed by ``change``."""
        if self.spec is None:
            return
        if completed:
            self.complete = True
            self.owed += self.spec.completion
        self.owed += change * self.spec.scale

    def pay(self, me: Payee, agents: Sequence[Payee], names: Sequence[str], *, end: bool) -> None:
        """Hand out what is owed: each tick (``PER_BLOCK``) or at the end (``MISSION_END``)."""
        if self.spec is None or not self.owed or (self.spec.density == "MISSION_END") != end:
            return
        owed, self.owed = self.owed, 0.0
        shares = share(owed, self.spec.distribution, self.name)
        me.pending_reward += shares.pop(None, owed)
        for world, name in zip(agents, names, strict=True):
            if world is not me and name in shares:
                world.pending_reward += shares[name]


def share(reward: float, distribution: str, me: str) -> dict[Optional[str], float]:
    """Malmo's ``adjustAndDistributeReward``: the agent's own share (key None: its
    name's factor, else ``me``'s, else nothing when a distribution is given) and each
    other named party's."""
    if not distribution.strip():
        return {None: reward}
    parties = [p.split(":") for p in distribution.split(" ") if p]
    names = [p[0] for p in parties]
    own = names.index(me) if me in names else names.index("me") if "me" in names else None
    if own is not None and len(parties[own]) != 2:
        return {None: reward}  # Java: a malformed share gives the agent it all
    out: dict[Optional[str], float] = {None: 0.0}
    if own is not None:
        out[None] = reward * float(parties[own][1])
    for i, p in enumerate(parties):
        if i != own and len(p) == 2:
            out[p[0]] = reward * float(p[1])
    return out
