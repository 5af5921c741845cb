"""The hard-coded Pendulum-v1 policy of the paper (sec. IV-B), written as a py_trees tree.

The tree reads the observation ``[cos θ, sin θ, θ̇]`` (θ = 0 upright) from the blackboard
and its leaves write the torque back::

    [o] Swing-up                              Selector, memory=False
        [-] Pump below pivot                  Sequence, memory=False
            --> Below pivot?                  cos θ < 0
            --> Pump energy                   torque = +max · sign(θ̇)
        --> Brake near top                    torque = −max · sign(θ̇)
"""

import itertools

import numpy as np
import py_trees
from py_trees.common import Access, Status

OBSERVATION_KEY = "observation"
"""Blackboard key (inside the tree's namespace) holding the current observation [3]."""

ACTION_KEY = "action"
"""Blackboard key (inside the tree's namespace) the action leaves write the torque to."""

DEFAULT_NAMESPACE = "/pendulum"
"""Blackboard namespace of a tree built without an explicit one."""

PENDULUM_MAX_TORQUE = 2.0
"""Pendulum-v1 clips torque to [-2, 2]."""

_tree_ids = itertools.count()


def _new_namespace() -> str:
    """Returns a blackboard namespace unique to one policy in this process.

    The py_trees blackboard is process-global; a namespace per tree keeps two policies
    living in the same process (tests, a learner evaluating while an actor runs) apart.
    """
    return f"/pendulum_{next(_tree_ids)}"


class BelowPivot(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS when the pendulum hangs below the pivot (cos θ < 0)."""

    def __init__(self, name: str, *, namespace: str) -> None:
        """Initialises the condition.

        Args:
            name: Node name shown in the tree.
            namespace: Blackboard namespace of the tree.
        """
        super().__init__(name)
        self.blackboard = self.attach_blackboard_client(name=name, namespace=namespace)
        self.blackboard.register_key(OBSERVATION_KEY, access=Access.READ)

    def update(self) -> Status:
        """Checks the sign of cos θ."""
        cos_theta = self.blackboard.get(OBSERVATION_KEY)[0]
        return Status.SUCCESS if cos_theta < 0.0 else Status.FAILURE


class _TorqueAction(py_trees.behaviour.Behaviour):
    """An action leaf: reads the observation, writes a torque to the blackboard."""

    def __init__(self, name: str, *, namespace: str, max_torque: float) -> None:
        """Initialises the action.

        Args:
            name: Node name shown in the tree.
            namespace: Blackboard namespace of the tree.
            max_torque: Torque magnitude written to the blackboard.
        """
        super().__init__(name)
        self.max_torque = max_torque
        self.blackboard = self.attach_blackboard_client(name=name, namespace=namespace)
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


def build_pendulum_tree(
    max_torque: float = PENDULUM_MAX_TORQUE, *, namespace: str = DEFAULT_NAMESPACE
) -> py_trees.trees.BehaviourTree:
    """Builds the hard-coded swing-up tree.

    Args:
        max_torque: Torque magnitude of both action leaves (the paper's bang-bang
            policy pushes with full torque, 2.0).
        namespace: Blackboard namespace for the observation and action keys. Trees
            ticked concurrently in one process need distinct namespaces.

    Returns:
        The tree: write ``<namespace>/observation``, tick, read ``<namespace>/action``.

    Raises:
        ValueError: If ``max_torque`` is outside (0, 2].
    """
    _check_max_torque(max_torque)
    pump = py_trees.composites.Sequence(
        name="Pump below pivot",
        memory=False,
        children=[
            BelowPivot("Below pivot?", namespace=namespace),
            PumpEnergy("Pump energy", namespace=namespace, max_torque=max_torque),
        ],
    )
    root = py_trees.composites.Selector(
        name="Swing-up",
        memory=False,
        children=[
            pump,
            BrakeNearTop("Brake near top", namespace=namespace, max_torque=max_torque),
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


class HardCodedPendulumPolicy:
    """The paper's hard-coded Pendulum-v1 policy, backed by a behaviour tree.

    Deterministic: it pushes along θ̇ below the pivot and against θ̇ above it.
    """

    def __init__(self, max_torque: float = PENDULUM_MAX_TORQUE) -> None:
        """Builds the tree and the blackboard client that feeds it.

        Args:
            max_torque: Torque magnitude of the bang-bang actions, in (0, 2].
        """
        self.max_torque = max_torque
        namespace = _new_namespace()
        self.tree = build_pendulum_tree(max_torque, namespace=namespace)
        self._blackboard = py_trees.blackboard.Client(
            name="HardCodedPendulumPolicy", namespace=namespace
        )
        self._blackboard.register_key(OBSERVATION_KEY, access=Access.WRITE)
        self._blackboard.register_key(ACTION_KEY, access=Access.WRITE)

    def __reduce__(self) -> tuple[type, tuple[float]]:
        # The blackboard is process-global: rebuild the tree where we are unpickled
        # (e.g. inside a Ray actor) instead of shipping clients of another process.
        return (HardCodedPendulumPolicy, (self.max_torque,))

    def _act_one(self, obs: np.ndarray) -> float:
        """Ticks the tree once on one observation.

        Args:
            obs: ``[cos θ, sin θ, θ̇]``.

        Returns:
            The torque written by the leaf that ran.
        """
        self._blackboard.set(OBSERVATION_KEY, obs)
        self._blackboard.set(ACTION_KEY, None)
        self.tree.tick()
        action = self._blackboard.get(ACTION_KEY)
        if self.tree.root.status != Status.SUCCESS or action is None:
            raise RuntimeError(
                f"pendulum tree ended with {self.tree.root.status} without writing an "
                "action; the 'Brake near top' fallback should always succeed"
            )
        return float(action)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Acts on a batch of observations, one tree tick per row.

        Args:
            obs: Observations of shape [B, 3], or a single observation of shape [3].

        Returns:
            float32 torques in [-max_torque, max_torque], shape [B, 1] (or [1] for a
            single observation).

        Raises:
            ValueError: If the observation does not have 3 features.
        """
        obs = np.asarray(obs, dtype=np.float64)
        if obs.ndim not in (1, 2) or obs.shape[-1] != 3:
            raise ValueError(
                f"observation has shape {obs.shape}; Pendulum-v1 expects [3] or [B, 3] "
                "rows of [cos θ, sin θ, θ̇]"
            )
        batch = np.atleast_2d(obs)
        actions = np.array([[self._act_one(row)] for row in batch], dtype=np.float32)
        actions = actions.reshape(batch.shape[0], 1)
        return actions[0] if obs.ndim == 1 else actions
