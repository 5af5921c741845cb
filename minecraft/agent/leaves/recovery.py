"""The leaves of the tree's "Re-plan" branch, which acts when the watchdog
(``agent.watchdog``) fires: a condition that holds while one re-plan is in force, and
the leaf that ends it."""

from __future__ import annotations

from py_trees.common import Status

from minecraft.agent.leaves.context import Leaf

RECOVER_KEY = "recover"
"""``ctx.memory`` key of the watchdog's last firing (``watchdog.Firing``) while its
re-plan is in force."""


class Recovering(Leaf):
    """SUCCESS while the watchdog's re-plan is ``plan`` and younger than ``ticks``; once
    older, the re-plan is dropped (the watchdog fires again if nothing moves)."""

    def __init__(self, plan: str, *, namespace: str, ticks: int) -> None:
        """Args: plan: "wood" or "elsewhere"; namespace: blackboard; ticks: how long
        the re-plan may run."""
        super().__init__(f"Re-plan: {plan}?", namespace=namespace)
        self.plan, self.ticks = plan, ticks

    def update(self) -> Status:
        """Read the last firing."""
        mem, tick = self.ctx.memory, self.ctx.percept.tick
        fired = mem.get(RECOVER_KEY)
        if fired is None or fired.plan != self.plan:
            return Status.FAILURE
        if tick - fired.tick > self.ticks:
            del mem[RECOVER_KEY]
            return Status.FAILURE
        return Status.SUCCESS


class EndRecovery(Leaf):
    """Action: the re-plan reached its aim; the quest goes on (SUCCESS)."""

    def __init__(self, *, namespace: str) -> None:
        """Args: namespace: blackboard."""
        super().__init__("End re-plan", namespace=namespace)

    def update(self) -> Status:
        """Drop the firing."""
        self.ctx.memory.pop(RECOVER_KEY, None)
        return Status.SUCCESS
