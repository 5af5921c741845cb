"""The two leaves every held-out tree is made of: a condition on the observation and an
action computed from it. graft writes the observation to ``/graft/observation`` and reads
the action from ``/graft/action``; it ticks a tree on single observations (also replayed
ones), so no leaf keeps state between ticks."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Access, Status

NAMESPACE = "/graft"


class Check(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS while ``test(observation)`` holds."""

    def __init__(self, name: str, test: Callable[[np.ndarray], bool]) -> None:
        super().__init__(name)
        self.test = test
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)

    def update(self) -> Status:
        return Status.SUCCESS if self.test(self.blackboard.observation) else Status.FAILURE


class Act(py_trees.behaviour.Behaviour):
    """Action: writes ``action(observation)``."""

    def __init__(self, name: str, action: Callable[[np.ndarray], Any]) -> None:
        super().__init__(name)
        self.action = action
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)
        self.blackboard.register_key("action", access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.action = self.action(self.blackboard.observation)
        return Status.SUCCESS


def either(name: str, when: Check, then: Act, otherwise: Act) -> py_trees.behaviour.Behaviour:
    """``[o] name: [-] (when -> then), otherwise``: a Selector over a guarded branch."""
    branch = py_trees.composites.Sequence(then.name, memory=False, children=[when, then])
    return py_trees.composites.Selector(name, memory=False, children=[branch, otherwise])
