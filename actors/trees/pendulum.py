"""The hard-coded Pendulum-v1 policy of the paper (sec. IV-B), written as a py_trees tree.

The tree reads the observation ``[cos θ, sin θ, θ̇]`` (θ = 0 upright) from the blackboard
key ``/graft/observation`` and its leaves write the torque to ``/graft/action``, graft's
convention for every hard-coded tree (actors/hardcoded.py). Presets name it by its import
string, ``hardcoded_policy: actors.trees.pendulum:swing_up``::

    [o] Swing-up                              Selector, memory=False
        [-] Pump below pivot                  Sequence, memory=False
            --> Below pivot?                  cos θ < 0
            --> Pump energy                   torque = +max · sign(θ̇)
        --> Brake near top                    torque = −max · sign(θ̇)
"""

import numpy as np
import py_trees
from gymnasium import spaces
from py_trees.common import Access, Status

from actors.hardcoded import ACTION_KEY, OBSERVATION_KEY

PENDULUM_MAX_TORQUE = 2.0
"""Pendulum-v1 clips torque to [-2, 2]."""


class BelowPivot(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS when the pendulum hangs below the pivot (cos θ < 0)."""

    def __init__(self, name: str) -> None:
        """Initialises the condition.

        Args:
            name: Node name shown in the tree.
        """
        super().__init__(name)
        self.blackboard = self.attach_blackboard_client(name=name)
        self.blackboard.register_key(OBSERVATION_KEY, access=Access.READ)

    def update(self) -> Status:
        """Checks the sign of cos θ."""
        cos_theta = self.blackboard.get(OBSERVATION_KEY)[0]
        return Status.SUCCESS if cos_theta < 0.0 else Status.FAILURE


class _TorqueAction(py_trees.behaviour.Behaviour):
    """An action leaf: reads the observation, writes a torque to the blackboard."""

    def __init__(self, name: str, *, max_torque: float) -> None:
        """Initialises the action.

        Args:
            name: Node name shown in the tree.
            max_torque: Torque magnitude written to the blackboard.
        """
        super().__init__(name)
        self.max_torque = max_torque
        self.blackboard = self.attach_blackboard_client(name=name)
        self.blackboard.register_key(OBSERVATION_KEY, access=Access.READ)
        self.blackboard.register_key(ACTION_KEY, access=Access.WRITE)

    def torque(self, theta_dot: float) -> float:
        raise NotImplementedError

    def update(self) -> Status:
        self.blackboard.set(ACTION_KEY, self.torque(self.blackboard.get(OBSERVATION_KEY)[2]))
        return Status.SUCCESS


class PumpEnergy(_TorqueAction):
    """Action: push with full torque in the direction of the angular velocity.

    At rest (θ̇ = 0) it pushes in the positive direction, so a pendulum hanging still at
    the bottom is kicked into swinging rather than left there forever.
    """

    def torque(self, theta_dot: float) -> float:
        """``+max · sign(θ̇)`` (sign(0) taken as +1)."""
        return (1.0 if theta_dot >= 0.0 else -1.0) * self.max_torque


class BrakeNearTop(_TorqueAction):
    """Action: push with full torque against the angular velocity.

    At rest (θ̇ = 0) there is nothing to brake and it applies no torque.
    """

    def torque(self, theta_dot: float) -> float:
        """``−max · sign(θ̇)``."""
        return -float(np.sign(theta_dot)) * self.max_torque


def _check_max_torque(max_torque: float) -> None:
    """Refuses torque magnitudes the environment would not honour."""
    if not 0.0 < max_torque <= PENDULUM_MAX_TORQUE:
        raise ValueError(
            f"max_torque={max_torque} must be in (0, {PENDULUM_MAX_TORQUE}]: Pendulum-v1 "
            f"clips torque to ±{PENDULUM_MAX_TORQUE}, so a larger value would be silently "
            "clipped and a non-positive one would reverse or cancel the policy."
        )


def build_pendulum_tree(max_torque: float = PENDULUM_MAX_TORQUE) -> py_trees.trees.BehaviourTree:
    """Builds the hard-coded swing-up tree.

    Args:
        max_torque: Torque magnitude of both action leaves (the paper's bang-bang
            policy pushes with full torque, 2.0).

    Returns:
        The tree: write ``/graft/observation``, tick, read ``/graft/action``.

    Raises:
        ValueError: If ``max_torque`` is outside (0, 2].
    """
    _check_max_torque(max_torque)
    pump = py_trees.composites.Sequence(
        name="Pump below pivot",
        memory=False,
        children=[
            BelowPivot("Below pivot?"),
            PumpEnergy("Pump energy", max_torque=max_torque),
        ],
    )
    root = py_trees.composites.Selector(
        name="Swing-up",
        memory=False,
        children=[
            pump,
            BrakeNearTop("Brake near top", max_torque=max_torque),
        ],
    )
    tree = py_trees.trees.BehaviourTree(root)
    # py_trees leaves a node that was not ticked with its status from an earlier
    # tick; the snapshot records what the last tick actually visited.
    tree.visitors.append(py_trees.visitors.SnapshotVisitor())
    return tree


def _snapshot(tree: py_trees.trees.BehaviourTree) -> py_trees.visitors.SnapshotVisitor:
    """Returns the tree's snapshot visitor, refusing trees built without one."""
    for visitor in tree.visitors:
        if isinstance(visitor, py_trees.visitors.SnapshotVisitor):
            return visitor
    raise ValueError("tree has no SnapshotVisitor; build it with build_pendulum_tree()")


def last_tick_statuses(tree: py_trees.trees.BehaviourTree) -> dict[str, Status | None]:
    """Status of every tree node in the last tick, by name; None for those not ticked.

    Args:
        tree: A tree from :func:`build_pendulum_tree`.

    Returns:
        ``{node name: status}`` in depth-first order.
    """
    visited = _snapshot(tree).visited
    return {node.name: visited.get(node.id) for node in tree.root.iterate()}


def render_tree_ascii(
    tree: py_trees.trees.BehaviourTree | None = None, *, show_status: bool = False
) -> str:
    """Renders a tree as py_trees' ASCII art.

    Args:
        tree: The tree to render; a freshly built pendulum tree when None.
        show_status: Mark the nodes the last tick visited with their status.

    Returns:
        The multi-line ASCII drawing.
    """
    tree = tree if tree is not None else build_pendulum_tree()
    if not show_status:
        return py_trees.display.ascii_tree(tree.root)
    snapshot = _snapshot(tree)
    return py_trees.display.ascii_tree(
        tree.root,
        show_status=True,
        visited=snapshot.visited,
        previously_visited=snapshot.previously_visited,
    )


def swing_up(action_space: spaces.Box) -> py_trees.trees.BehaviourTree:
    """The hard-coded policy's factory (``hardcoded_policy: actors.trees.pendulum:swing_up``):
    the swing-up tree pushing with the action space's full torque (2.0 on Pendulum-v1).

    Raises:
        ValueError: If the action space is not a one-torque box within (0, 2].
    """
    if not isinstance(action_space, spaces.Box) or action_space.shape != (1,):
        raise ValueError(f"the swing-up tree acts one torque, not {action_space}")
    return build_pendulum_tree(float(action_space.high[0]))
