"""Where the obtain-diamond tree's in-game time goes: every game tick is charged to the
leaf that was running when the action was sent, with its sub-tree and activity, plus
the dithering signs (a leaf re-entered without progress, ticks spent stuck).

``run_episode(..., profile=TimeProfile())`` feeds it; ``TimeProfile.summary()`` is a
picklable ``LeafTimes``; ``aggregate`` sums worlds.
"""

from __future__ import annotations

import statistics
from collections import Counter
from dataclasses import dataclass, field
from typing import Optional

from py_trees.behaviour import Behaviour

from minecraft.agent.leaves.context import Context
from minecraft.agent.leaves.goals import Ascend, Descend, Explore, MineTarget
from minecraft.agent.leaves.items import Craft
from minecraft.agent.leaves.percept import Percept
from minecraft.agent.leaves.survival import DigOut, Eat, EscapeLiquid
from minecraft.agent.leaves.travel import STUCK_TICKS, BreakBlock, StepTo

MISSION_START = "(mission start)"
"""Ticks before the tree first acted (the mission's loading, the first observation)."""

ACTIVITIES = (
    "travel", "digging", "searching", "descending", "crafting", "survival", "recovering",
    "waiting",
)  # fmt: skip
"""travel: walking (and breaking blocks in the way) to a chosen block or drop; digging:
mining the chosen block and waiting for its drop; searching: exploring for blocks not
in view (climbing to the surface for wood too); descending: digging down to a depth;
crafting; survival: eating, leaving a liquid; recovering: acting on a watchdog re-plan;
waiting: no action leaf running (mission start, a condition or chooser that failed, the
goal already held)."""

_SUBTREE_PREFIXES = ("Re-plan", "Ensure ", "Wood", "Diamond", "Fuel", "Survive", "Pick up drops")


@dataclass(frozen=True)
class LeafKey:
    """Where a tick went.

    Attributes:
        subtree: the innermost need the leaf serves ("Ensure cobblestone x3", "Wood",
            "Diamond", "Fuel", "Survive", "Pick up drops").
        leaf: the leaf's name ("Step to cell", "Mine target", "Craft furnace", ...).
        activity: one of ``ACTIVITIES``.
    """

    subtree: str
    leaf: str
    activity: str


START_KEY = LeafKey(MISSION_START, MISSION_START, "waiting")


def classify(tip: Optional[Behaviour]) -> LeafKey:
    """The sub-tree and activity of the running behaviour, from its place in the tree."""
    if tip is None:
        return LeafKey("(none)", "(none)", "waiting")
    names: list[str] = []
    node: Optional[Behaviour] = tip.parent
    while node is not None:
        names.append(node.name)
        node = node.parent
    subtree = next(
        (n for n in names if n.startswith(_SUBTREE_PREFIXES)), names[-1] if names else tip.name
    )
    acts = (MineTarget, Craft, Eat, EscapeLiquid, DigOut, Explore, Descend, Ascend, StepTo,
            BreakBlock)  # fmt: skip
    if isinstance(tip, acts) and any(n.startswith("Re-plan") for n in names):
        activity = "recovering"
    elif isinstance(tip, MineTarget):
        activity = "digging"
    elif isinstance(tip, Craft):
        activity = "crafting"
    elif isinstance(tip, (Eat, EscapeLiquid, DigOut)):
        activity = "survival"
    elif isinstance(tip, (Explore, Ascend)):
        activity = "searching"
    elif isinstance(tip, Descend):
        activity = "descending"
    elif isinstance(tip, (StepTo, BreakBlock)):
        # The travel sub-tree's purpose is the sequence that holds it.
        purpose = names[names.index("Travel") + 1] if "Travel" in names[:-1] else ""
        if purpose in ("Explore", "Go up for wood"):
            activity = "searching"
        elif purpose.startswith("Go down to"):
            activity = "descending"
        else:
            activity = "travel"
    else:
        activity = "waiting"  # a condition or chooser: nothing is acting
    return LeafKey(subtree, tip.name, activity)


@dataclass
class LeafTimes:
    """One episode's attribution (plain data: pickles across processes).

    Attributes:
        ticks: game ticks per leaf; they sum to the episode's ticks.
        entries: times each leaf became the running one.
        idle_entries: entries with no inventory change since the leaf last ran (the
            same leaf re-entered without progress: dithering).
        stuck_ticks: ticks per leaf spent jammed in one cell past the travel sub-tree's
            stuck threshold (``STUCK_TICKS``).
        given_up: targets abandoned (unreachable, unbreakable or over budget).
        last: the leaf running when the episode ended.
        longest_wait: the longest run of consecutive ticks spent waiting (no action
            leaf running; one waiting leaf or several in turn).
        longest_wait_leaf: the waiting leaf that began that run.
        watchdog: times the watchdog fired (``watchdog.Watchdog``), per leaf that was
            running when it did.
    """

    ticks: dict[LeafKey, int] = field(default_factory=dict)
    entries: dict[LeafKey, int] = field(default_factory=dict)
    idle_entries: dict[LeafKey, int] = field(default_factory=dict)
    stuck_ticks: dict[LeafKey, int] = field(default_factory=dict)
    given_up: int = 0
    last: LeafKey = START_KEY
    longest_wait: int = 0
    longest_wait_leaf: LeafKey = START_KEY
    watchdog: dict[LeafKey, int] = field(default_factory=dict)

    @property
    def total(self) -> int:
        """All attributed ticks."""
        return sum(self.ticks.values())

    def by(self, attr: str) -> dict[str, int]:
        """Ticks per ``subtree``, ``leaf`` or ``activity``."""
        out: Counter[str] = Counter()
        for k, n in self.ticks.items():
            out[getattr(k, attr)] += n
        return dict(out)


class TimeProfile:
    """Charges each tick to the running leaf. Cheap: one ``tip()`` walk per tick, the
    leaf's key cached per behaviour, no copies of the tree or the percept."""

    def __init__(self) -> None:
        self._keys: dict[int, LeafKey] = {}
        self._key = START_KEY
        self._last_tick = 0
        self._stuck = False
        self._inv: tuple[tuple[str, int], ...] = ()
        self._inv_at_leave: dict[LeafKey, tuple[tuple[str, int], ...]] = {}
        self._given_up = 0
        self.ticks: Counter[LeafKey] = Counter()
        self.entries: Counter[LeafKey] = Counter()
        self.idle_entries: Counter[LeafKey] = Counter()
        self.stuck_ticks: Counter[LeafKey] = Counter()
        self.watchdog: Counter[LeafKey] = Counter()
        self._wait = 0  # consecutive waiting ticks so far
        self._wait_leaf = START_KEY
        self.longest_wait = 0
        self.longest_wait_leaf = START_KEY

    @property
    def current(self) -> LeafKey:
        """The leaf whose action was sent last."""
        return self._key

    def observed(self, p: Percept) -> None:
        """A new observation: the ticks since the last one go to the leaf that acted."""
        dt = p.tick - self._last_tick
        if dt > 0:
            self._charge(dt)
            if self._stuck:
                self.stuck_ticks[self._key] += dt
            self._last_tick = p.tick
        self._inv = tuple(sorted(p.inventory.items()))

    def _charge(self, dt: int) -> None:
        self.ticks[self._key] += dt
        if self._key.activity != "waiting":
            self._wait = 0
            return
        if self._wait == 0:
            self._wait_leaf = self._key
        self._wait += dt
        if self._wait > self.longest_wait:
            self.longest_wait, self.longest_wait_leaf = self._wait, self._wait_leaf

    def fired(self) -> None:
        """The watchdog fired while the current leaf was running."""
        self.watchdog[self._key] += 1

    def acted(self, tip: Optional[Behaviour], ctx: Context) -> None:
        """The tree was ticked; ``tip`` is its running behaviour, whose action is sent."""
        key = self._keys.get(id(tip))
        if key is None:
            key = classify(tip)
            self._keys[id(tip)] = key
        if key != self._key:
            self._inv_at_leave[self._key] = self._inv
            self.entries[key] += 1
            if self._inv_at_leave.get(key) == self._inv:
                self.idle_entries[key] += 1
            self._key = key
        self._stuck = isinstance(tip, StepTo) and ctx.memory.get("stuck_ticks", 0) > STUCK_TICKS
        self._given_up = len(ctx.memory.get("given_up", ()))

    def finish(self, tick: int) -> None:
        """The episode ended at ``tick``: charge what is left to the last leaf."""
        dt = tick - self._last_tick
        if dt > 0:
            self._charge(dt)
            self._last_tick = tick

    def summary(self) -> LeafTimes:
        """The attribution so far, as plain data."""
        return LeafTimes(
            ticks=dict(self.ticks),
            entries=dict(self.entries),
            idle_entries=dict(self.idle_entries),
            stuck_ticks=dict(self.stuck_ticks),
            given_up=self._given_up,
            last=self._key,
            longest_wait=self.longest_wait,
            longest_wait_leaf=self.longest_wait_leaf,
            watchdog=dict(self.watchdog),
        )


@dataclass(frozen=True)
class Row:
    """One line of the over-worlds table.

    Attributes:
        name: the leaf, sub-tree or activity.
        share: fraction of all worlds' ticks.
        mean, median: ticks per world (0 in a world where it never ran).
        worlds: worlds where it ran.
        idle_entries: re-entries without progress, summed over worlds.
        stuck: stuck ticks, summed over worlds.
    """

    name: str
    share: float
    mean: float
    median: float
    worlds: int
    idle_entries: int
    stuck: int


def aggregate(episodes: list[LeafTimes], attr: str) -> list[Row]:
    """Rows per ``attr`` ("leaf", "subtree", "activity") over worlds, largest share first.

    A leaf row's name is "leaf [subtree: activity]", so that a leaf used under several
    needs, or for several purposes in one (the travel sub-tree's "Break block" when
    reaching a target, exploring or descending), stays apart.
    """

    def name(k: LeafKey) -> str:
        if attr == "leaf":
            return f"{k.leaf} [{k.subtree}: {k.activity}]"
        return str(getattr(k, attr))

    per_world: list[Counter[str]] = []
    idle: Counter[str] = Counter()
    stuck: Counter[str] = Counter()
    for e in episodes:
        c: Counter[str] = Counter()
        for k, n in e.ticks.items():
            c[name(k)] += n
        per_world.append(c)
        for k, n in e.idle_entries.items():
            idle[name(k)] += n
        for k, n in e.stuck_ticks.items():
            stuck[name(k)] += n
    total = sum(sum(c.values()) for c in per_world) or 1
    names: set[str] = set().union(*per_world)
    rows = []
    for label in names:
        xs = [c.get(label, 0) for c in per_world]
        rows.append(
            Row(
                name=label,
                share=sum(xs) / total,
                mean=statistics.fmean(xs),
                median=float(statistics.median(xs)),
                worlds=sum(1 for x in xs if x),
                idle_entries=idle[label],
                stuck=stuck[label],
            )
        )
    return sorted(rows, key=lambda r: (-r.share, r.name))
