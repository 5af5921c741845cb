"""A hard-coded Acrobot-v1 policy, written as a py_trees tree: energy pumping.

Acrobot's observation is ``[cos θ1, sin θ1, cos θ2, sin θ2, θ̇1, θ̇2]`` and its three
actions are torques −1, 0 and +1 on the joint between the links (0, 1, 2). The tree pumps
energy into the swing by pushing the lower link the way it already turns::

    [o] Pump                          Selector, memory=False
        [-] Lower link turning +?     Sequence, memory=False
            --> Turning +?            θ̇2 > 0
            --> Push +                action 2 (torque +1)
        --> Push −                    action 0 (torque −1)

It raises the tip above the line in about 90 steps (of the 500 allowed); it ignores where
the upper link is, so its swings are not timed to the top. That is the room RL has.
"""

from __future__ import annotations

import py_trees
from py_trees.common import Access, Status

from actors.hardcoded import ACTION_KEY, OBSERVATION_KEY

MINUS, PLUS = 0, 2
"""Acrobot-v1's actions for torques −1 and +1."""


class TurningPositive(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS while the lower link turns in the positive sense (θ̇2 > 0)."""

    def __init__(self) -> None:
        super().__init__("Turning +?")
        self.blackboard = self.attach_blackboard_client(name=self.name)
        self.blackboard.register_key(OBSERVATION_KEY, access=Access.READ)

    def update(self) -> Status:
        return Status.SUCCESS if self.blackboard.get(OBSERVATION_KEY)[5] > 0.0 else Status.FAILURE


class Push(py_trees.behaviour.Behaviour):
    """Action: writes one of the torque actions."""

    def __init__(self, name: str, action: int) -> None:
        super().__init__(name)
        self.action = action
        self.blackboard = self.attach_blackboard_client(name=name)
        self.blackboard.register_key(ACTION_KEY, access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.set(ACTION_KEY, self.action)
        return Status.SUCCESS


def pump() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    turning = py_trees.composites.Sequence(
        "Lower link turning +?", memory=False, children=[TurningPositive(), Push("Push +", PLUS)]
    )
    return py_trees.composites.Selector(
        "Pump", memory=False, children=[turning, Push("Push −", MINUS)]
    )
