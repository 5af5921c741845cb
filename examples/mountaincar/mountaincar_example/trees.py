"""The energy-pumping policy for MountainCarContinuous-v0, written as a py_trees tree.

The car is too weak to drive up the hill; it gets there by swinging: push in the direction
it already moves, so that every push adds energy. The tree reads the observation
``[position, velocity]`` from graft's blackboard key ``/graft/observation`` and writes the
force (in [-1, 1]) to ``/graft/action``::

    [o] Energy pumping               Selector, memory=False
        [-] Swing left               Sequence, memory=False
            --> Moving left?         velocity < 0
            --> Push left            force = -1
        --> Push right               force = +1 (moving right, or standing still)

It reaches the flag from every start, in about 100 steps, always at full force: the
environment charges 0.1 · force² per step, so a policy that pushes less where a push is
not needed returns more. That is the room RL has to improve on it.
"""

from __future__ import annotations

import py_trees
from py_trees.common import Access, Status

NAMESPACE = "/graft"
"""graft writes the observation to /graft/observation and reads /graft/action."""


class MovingLeft(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS while the car moves left (velocity < 0)."""

    def __init__(self) -> None:
        super().__init__("Moving left?")
        self.blackboard = self.attach_blackboard_client(name=self.name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)

    def update(self) -> Status:
        _, velocity = self.blackboard.observation
        return Status.SUCCESS if velocity < 0.0 else Status.FAILURE


class Push(py_trees.behaviour.Behaviour):
    """Action: full force in one direction."""

    def __init__(self, name: str, force: float) -> None:
        super().__init__(name)
        self.force = force
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("action", access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.action = [self.force]
        return Status.SUCCESS


def energy_pumping() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    swing_left = py_trees.composites.Sequence(
        "Swing left", memory=False, children=[MovingLeft(), Push("Push left", -1.0)]
    )
    return py_trees.composites.Selector(
        "Energy pumping", memory=False, children=[swing_left, Push("Push right", 1.0)]
    )
