"""The tree's watchdog: it notices when the agent makes no progress and asks the tree to
re-plan, whatever leaf holds it (a condition waiting for an item nothing fetches, a
chooser that keeps deciding, a step that never lands).

Progress is a change of the inventory or of the feet cell. The watchdog fires when

* **idle**: no progress and no command sent (no action leaf running) for
  ``idle_ticks`` ticks, or
* **stalled**: no progress for ``stall_ticks`` ticks, even with commands sent (jammed
  against a block, a jump held against a ceiling).

On firing it abandons the sub-goal in hand (the target is given up, the planned step
and the exploring, descending and climbing goals are dropped, so they are chosen anew)
and writes ``ctx.memory[RECOVER_KEY]``; the tree's "Re-plan" branch
(``leaves.recovery``) acts on it: go up for wood when none is held, else explore
elsewhere. The runner (``tree_episode.TreeEpisode``) checks it after each tick.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

from minecraft.agent.leaves.context import Commands, Context
from minecraft.agent.leaves.percept import Percept
from minecraft.agent.leaves.recovery import RECOVER_KEY

IDLE_TICKS = 100  # 5 s with nothing sent and nothing changing
STALL_TICKS = 600  # 30 s with nothing changing, commands or not
WOOD = ("log", "planks", "stick")


def acting(cmd: Commands) -> bool:
    """An action leaf wrote something this tick (a movement, an action or a command)."""
    moving = cmd.move or cmd.strafe or cmd.turn or cmd.pitch
    return bool(moving or cmd.jump or cmd.attack or cmd.use or cmd.once)


@dataclass(frozen=True)
class Firing:
    """One firing: when, why ("idle" or "stalled"), and the re-plan chosen ("wood" when
    no wood is held, else "elsewhere")."""

    tick: int
    reason: str
    plan: str


class Watchdog:
    """Counts ticks without progress; ``check`` after each tick of the tree.

    Args:
        idle_ticks: ticks with no progress and no command before it fires.
        stall_ticks: ticks with no progress at all before it fires.
    """

    def __init__(self, *, idle_ticks: int = IDLE_TICKS, stall_ticks: int = STALL_TICKS) -> None:
        if not 0 < idle_ticks <= stall_ticks:
            raise ValueError(
                f"need 0 < idle_ticks <= stall_ticks, got {idle_ticks} and {stall_ticks}"
            )
        self.idle_ticks, self.stall_ticks = idle_ticks, stall_ticks
        self._state: Optional[tuple[object, ...]] = None
        self._changed = 0  # tick of the last progress
        self._idle_since: Optional[int] = None
        self.firings = 0

    def check(self, ctx: Context) -> Optional[Firing]:
        """Account for the tick just decided (``ctx.percept`` and the commands the tree
        wrote); on firing, record the re-plan in ``ctx.memory[RECOVER_KEY]``."""
        p = ctx.percept
        state = (p.cell, tuple(sorted(p.inventory.items())))
        if state != self._state:
            self._state, self._changed, self._idle_since = state, p.tick, None
        if acting(ctx.commands):
            self._idle_since = None
        elif self._idle_since is None:
            self._idle_since = p.tick
        reason = None
        if self._idle_since is not None and p.tick - self._idle_since >= self.idle_ticks:
            reason = "idle"
        elif p.tick - self._changed >= self.stall_ticks:
            reason = "stalled"
        if reason is None:
            return None
        # The next firing needs a new wait of its own.
        self._changed = p.tick
        self._idle_since = None if self._idle_since is None else p.tick
        self.firings += 1
        fired = Firing(p.tick, reason, "elsewhere" if _has_wood(p) else "wood")
        abandon(ctx)
        ctx.memory[RECOVER_KEY] = fired
        return fired


def abandon(ctx: Context) -> None:
    """Give up the sub-goal in hand: its target, its planned step, and the goals of the
    exploring, descending and climbing leaves (chosen anew next time)."""
    if ctx.target is not None:
        ctx.memory.setdefault("given_up", set()).add(ctx.target)
    ctx.target, ctx.plan_step, ctx.goals = None, None, frozenset()
    for key in ("explore_tunnel", "explore_surface", "descend", "ascend"):
        ctx.memory.pop(key, None)


def _has_wood(p: Percept) -> bool:
    return any(p.count(w) for w in WOOD)
