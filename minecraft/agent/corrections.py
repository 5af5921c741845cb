"""Learned corrections deployed inside the obtain-diamond tree, each at the leaf it was
trained for, reading what that leaf already sees:

- **travel**: while "Step to cell" walks, ``a = μ(s) + clip(π(s))`` over [move, strafe,
  turn, jump] replaces the leaf's commands; s is the travel task's observation
  (``travel_control.observation``) built from the tree's own plan step and goals.
- **drops**: when a wanted item first lies within reach of "Pick up drops", a choice in
  {0: chase it (the tree), 1: leave it}; s is ``drop_observation`` (the item, how many
  are held, where it lies, which tools the quest has made). A left item is never chased
  (walking near it still picks it up).

A policy is a plain callable on one observation; the run folder that trained it is
loaded above this layer (``graft.trained.load_corrections``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Optional

import numpy as np

from minecraft.agent.leaves.context import Context
from minecraft.agent.leaves.percept import ItemSeen, Percept
from minecraft.agent.leaves.travel import STUCK_TICKS, StepTo
from minecraft.agent.travel_control import JUMP_OFF, JUMP_ON, observation
from minecraft.agent.tree_profile import classify

Policy = Callable[[np.ndarray], np.ndarray]
"""One observation -> the action (travel: [4] floats; drops: an index)."""

DROP_REACH = 4.0  # blocks (|dx| + |dy| + |dz|): the tree's "Drop nearby?" range
SKIPPED_KEY = "skipped_drops"  # ctx.memory: uids of items a correction chose to leave
DROP_ITEMS = (
    "log", "cobblestone", "iron_ore", "diamond", "coal", "apple", "porkchop", "beef",
)  # fmt: skip
"""The items the tree picks up (``diamond_tree.WANTED``), in the one-hot's order."""
TOOLS = ("wooden_pickaxe", "stone_pickaxe", "furnace", "iron_pickaxe")
DROP_OBS_DIM = len(DROP_ITEMS) + 5 + len(TOOLS)
DROP_ACTIONS = ("chase", "leave")


def new_drops(p: Percept, decided: Iterable[str]) -> list[ItemSeen]:
    """Wanted items within the tree's reach whose uid has not been decided, nearest first."""
    seen = set(decided)
    near = [
        (abs(it.x - p.x) + abs(it.y - p.y) + abs(it.z - p.z), it)
        for it in p.items
        if it.name in DROP_ITEMS and it.uid not in seen
    ]
    return [it for d, it in sorted(near, key=lambda di: di[0]) if d <= DROP_REACH]


def drop_observation(p: Percept, item: ItemSeen) -> np.ndarray:
    """float32 [DROP_OBS_DIM]::

    [0:8]   the item, one-hot over DROP_ITEMS
    [8]     how many of it are held / 16 (at most 4)
    [9:12]  item minus feet (x, y, z) / 4
    [12]    |dx| + |dy| + |dz| / 4
    [13:17] held: wooden pickaxe, stone pickaxe, furnace, iron pickaxe
    """
    out = np.zeros(DROP_OBS_DIM, np.float32)
    out[DROP_ITEMS.index(item.name)] = 1.0
    k = len(DROP_ITEMS)
    out[k] = min(p.count(item.name) / 16.0, 4.0)
    d = (item.x - p.x, item.y - p.y, item.z - p.z)
    out[k + 1 : k + 4] = [v / 4.0 for v in d]
    out[k + 4] = sum(abs(v) for v in d) / 4.0
    out[k + 5 :] = [float(p.count(t) > 0) for t in TOOLS]
    return out


class TravelCorrection:
    """The travel correction at "Step to cell": call ``apply`` after each tree tick.

    Args:
        policy: obs -> [move, strafe, turn, jump].
        activities: the activities (``tree_profile.ACTIVITIES``) whose walks it corrects,
            for example ("searching",): the walks of "Explore" across open terrain, which
            are most like the travel task's; None: every walk.
    """

    def __init__(self, policy: Policy, activities: Optional[frozenset[str]] = None) -> None:
        self.policy, self.activities = policy, activities
        self._previous: Optional[tuple[float, float, float]] = None
        self.last: Optional[np.ndarray] = None
        """The correction π(s) = a − μ(s) applied at the last tick (None: not walking)."""

    def apply(self, tip: object, ctx: Context, elapsed: int) -> None:
        """Replace the walking commands with μ(s) + clip(π(s)) when ``tip`` walks."""
        p, cmd = ctx.percept, ctx.commands
        previous, self._previous = self._previous, (p.x, p.y, p.z)
        self.last = None
        if not isinstance(tip, StepTo) or ctx.plan_step is None:
            return
        if self.activities is not None and classify(tip).activity not in self.activities:
            return
        mu = np.array([cmd.move, cmd.strafe, cmd.turn, JUMP_ON if cmd.jump else JUMP_OFF])
        waypoint = ctx.plan_step[1]
        destination = min(ctx.goals, key=lambda g: math.dist(g, p.cell)) if ctx.goals else waypoint
        s = observation(
            p,
            mu=mu.astype(np.float32),
            waypoint=waypoint,
            destination=destination,
            previous=previous,
            stuck_fraction=ctx.memory.get("stuck_ticks", 0) / STUCK_TICKS,
            elapsed=max(1, elapsed),
        )
        a = np.clip(np.asarray(self.policy(s), np.float64), -1.0, 1.0)
        cmd.move, cmd.strafe, cmd.turn = float(a[0]), float(a[1]), float(a[2])
        cmd.jump = bool(a[3] > 0)
        self.last = a - mu


@dataclass
class Corrections:
    """The learned corrections deployed in one episode (None: the tree's own leaf).

    Attributes:
        travel: obs -> [move, strafe, turn, jump] (μ + clip(π), the trained behaviour).
        drops: obs -> 0 (chase) or 1 (leave).
        travel_activities: the activities whose walks ``travel`` corrects (None: every
            walk; ``TravelCorrection``).
    """

    travel: Optional[Policy] = None
    drops: Optional[Policy] = None
    travel_activities: Optional[frozenset[str]] = None

    def __bool__(self) -> bool:
        return self.travel is not None or self.drops is not None
