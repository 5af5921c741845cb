"""A hand-written gait for MuJoCo's HalfCheetah-v5, as a py_trees tree.

The observation is ``[z, pitch, 6 joint angles, vx, vz, pitch rate, 6 joint velocities]``
(the joints in the order back thigh, shin, foot, front thigh, shin, foot) and the action
the six joint torques in [-1, 1]. The reward is the forward speed less 0.1·|action|² per
step, over 1,000 steps. The tree reads the observation from graft's blackboard key
``/graft/observation`` and writes the action to ``/graft/action``::

    [o] Cheetah                     Selector, memory=False
        [-] Tilted                  Sequence, memory=False
            --> Tilted?             |pitch| above a limit (rearing or diving)
            --> Lean back           both thighs at full torque against the tilt
        --> Run                     the gait below

The gait is a relay oscillator read from the observation alone (graft ticks the tree on
single observations, also on replayed ones, so it keeps no state): the back thigh pushes at
full torque in the direction it moves and turns at the ends of its stroke; the phase of
that swing, the angle of (angle, velocity) around the stroke's centre, drives the other
joints towards sine targets at fixed phase offsets through a PD law. One fixed stride, no
speed or terrain feedback, and full torque where less would do: the cheetah runs, but
slowly, rears up often and sometimes flips onto its back (where it stays). That is the
room RL has.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import py_trees
from py_trees.common import Access, Status

NAMESPACE = "/graft"
"""graft writes the observation to /graft/observation and reads /graft/action."""

Observation = np.ndarray
"""[z, pitch, 6 joint angles, vx, vz, pitch rate, 6 joint velocities]."""

PITCH, ANGLES, VELOCITIES = 1, slice(2, 8), slice(11, 17)
"""Where the observation holds the body's pitch, the joint angles and their velocities."""

TILT_LIMIT = 1.0
"""|pitch| (radians) past which the tree stops running and leans back."""
STROKE_CENTRE = -0.07
"""Back thigh angle (radians) at the middle of its stroke ..."""
STROKE_HALF = 0.53
"""... and half the stroke: the relay turns the thigh at centre ± this."""
STROKE_RATE = 10.0
"""Angular frequency (rad/s) that scales the thigh's velocity into the phase plane."""
AMPLITUDES = np.array([0.0, 0.1, 0.33, 0.46, 0.37, 0.0])
"""Sine target amplitudes (radians) of the joints that follow the back thigh (its own and
the front foot's are unused: the thigh is the relay, the front foot is held at 0)."""
OFFSETS = np.array([0.0, 3.58, -2.95, 4.3, 6.07, 0.0])
"""Phase offsets (radians) of those targets from the back thigh's swing."""
KP, KD = 1.6, 0.07
"""PD gains towards the targets (torque per radian, per rad/s)."""


def tilted(obs: Observation) -> bool:
    return bool(abs(obs[PITCH]) > TILT_LIMIT)


def lean_back(obs: Observation) -> list[float]:
    """Both thighs at full torque towards the tilt's sign, which turns the body back."""
    push = float(np.sign(obs[PITCH]))
    return [push, 0.0, 0.0, push, 0.0, 0.0]


def stride_phase(obs: Observation) -> float:
    """The back thigh's phase: the angle of (angle, velocity), each scaled to the stroke."""
    angle = (obs[ANGLES][0] - STROKE_CENTRE) / STROKE_HALF
    velocity = obs[VELOCITIES][0] / (STROKE_RATE * STROKE_HALF)
    return float(np.arctan2(-velocity, angle))


def run(obs: Observation) -> list[float]:
    """The gait: the back thigh's relay, the other joints' PD towards their sine targets."""
    angles, velocities = obs[ANGLES], obs[VELOCITIES]
    targets = AMPLITUDES * np.sin(stride_phase(obs) + OFFSETS)
    torques = np.clip(KP * (targets - angles) - KD * velocities, -1.0, 1.0)
    thigh = angles[0] - STROKE_CENTRE
    if thigh > STROKE_HALF:
        torques[0] = -1.0  # at the front end of the stroke: turn back
    elif thigh < -STROKE_HALF:
        torques[0] = 1.0  # at the back end: turn forward
    else:
        torques[0] = 1.0 if velocities[0] > 0 else -1.0  # keep pushing the way it moves
    return [float(t) for t in torques]


class Check(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS when ``test(observation)`` holds, else FAILURE."""

    def __init__(self, name: str, test: Callable[[Observation], bool]) -> None:
        super().__init__(name)
        self.test = test
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)

    def update(self) -> Status:
        return Status.SUCCESS if self.test(self.blackboard.observation) else Status.FAILURE


class Drive(py_trees.behaviour.Behaviour):
    """Action: writes ``command(observation)``, the six joint torques."""

    def __init__(self, name: str, command: Callable[[Observation], list[float]]) -> None:
        super().__init__(name)
        self.command = command
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)
        self.blackboard.register_key("action", access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.action = self.command(self.blackboard.observation)
        return Status.SUCCESS


def gait() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    return py_trees.composites.Selector(
        "Cheetah",
        memory=False,
        children=[
            py_trees.composites.Sequence(
                "Tilted",
                memory=False,
                children=[Check("Tilted?", tilted), Drive("Lean back", lean_back)],
            ),
            Drive("Run", run),
        ],
    )
