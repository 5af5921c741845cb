"""A hard-coded CartPole-v1 policy as a py_trees tree writing DISCRETE actions.

CartPole's observation is ``[cart position, cart velocity, pole angle, pole angular
velocity]`` and its two actions are 0 (push the cart left) and 1 (push it right). The tree
reads the observation from graft's blackboard key ``/graft/observation`` and writes the
action, an ``int``, to ``/graft/action``::

    [o] Balance                      Selector, memory=False
        [-] Catch falling right      Sequence, memory=False
            --> Falling right?       pole angular velocity > 0
            --> Push right           action = 1
        --> Push left                action = 0

Moving the cart under the falling pole keeps it up for about 200 of the 500 steps: the
tree ignores where the cart is, so it drifts off the track. That is the room RL has.
"""

from __future__ import annotations

import py_trees
from py_trees.common import Access, Status

NAMESPACE = "/graft"
"""graft writes the observation to /graft/observation and reads /graft/action."""

LEFT, RIGHT = 0, 1
"""CartPole-v1's actions."""


class FallingRight(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS while the pole rotates to the right (angular velocity > 0)."""

    def __init__(self) -> None:
        super().__init__("Falling right?")
        self.blackboard = self.attach_blackboard_client(name=self.name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)

    def update(self) -> Status:
        angular_velocity = self.blackboard.observation[3]
        return Status.SUCCESS if angular_velocity > 0.0 else Status.FAILURE


class Push(py_trees.behaviour.Behaviour):
    """Action: writes one of the two discrete actions."""

    def __init__(self, name: str, action: int) -> None:
        super().__init__(name)
        self.action = action
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("action", access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.action = self.action
        return Status.SUCCESS


def balance() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    catch_right = py_trees.composites.Sequence(
        "Catch falling right", memory=False, children=[FallingRight(), Push("Push right", RIGHT)]
    )
    return py_trees.composites.Selector(
        "Balance", memory=False, children=[catch_right, Push("Push left", LEFT)]
    )
