"""Hopper-v5 and Walker2d-v5 (joint torques in [-1, 1]): stand up and lean forward.

Hopper's observation is ``[z, pitch, thigh, leg, foot, vx, vz, pitch rate, 3 joint
velocities]``; Walker2d's ``[z, pitch, 6 joint angles (right thigh, leg, foot, left ...),
vx, vz, pitch rate, 6 joint velocities]``. Both pay 1 per step while healthy (upright,
high enough) plus the forward speed. The tree is a balance controller, not a gait: every
joint is held straight by a PD law, each hip turns the torso towards a small forward lean,
and each ankle keeps the body over the foot::

    [o] Stand                       Selector, memory=False
        [-] Catch                   Sequence, memory=False
            --> Tipping?            |pitch - lean| > 0.15 rad
            --> Straighten up       the same law towards lean 0
        --> Lean forward            the law towards lean LEAN

It stays up for the whole 1,000 steps and creeps forward: about 1,000 on both tasks. A
policy that hops or walks earns the rest.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import py_trees

from heldout_example.leaves import Act, Check, either

TIPPING = 0.15
"""|pitch - lean| (rad) past which the tree straightens up instead of leaning."""


@dataclass(frozen=True)
class Body:
    """Where one robot's observation holds its parts, and the controller's gains."""

    joints: slice
    joint_velocities: slice
    pitch_rate: int
    legs: tuple[tuple[int, int, int], ...]
    """Each leg's (hip, knee, ankle) joint indices."""
    kp: float
    kd: float
    hip: float
    ankle: float
    ankle_rate: float
    lean: float


HOPPER = Body(slice(2, 5), slice(8, 11), 7, ((0, 1, 2),), 1.0, 0.1, -3.0, -4.0, -0.4, 0.15)
WALKER = Body(
    slice(2, 8), slice(11, 17), 10, ((0, 1, 2), (3, 4, 5)), 3.0, 0.1, -3.0, -4.0, 0.0, 0.05
)


def balance(body: Body, obs: np.ndarray, lean: float) -> np.ndarray:
    """The PD balance law above, towards a torso pitch of `lean`."""
    pitch, rate = obs[1], obs[body.pitch_rate]
    q, dq = obs[body.joints], obs[body.joint_velocities]
    torque = -body.kp * q - body.kd * dq
    for hip, knee, ankle in body.legs:
        torque[hip] += body.hip * (pitch - lean + 0.3 * rate)
        tilt = pitch + q[hip] + q[knee] + q[ankle] - lean
        tilt_rate = rate + dq[hip] + dq[knee] + dq[ankle]
        torque[ankle] += body.ankle * tilt + body.ankle_rate * tilt_rate
    return np.clip(torque, -1.0, 1.0).astype(np.float32)


def _stand(name: str, body: Body) -> py_trees.behaviour.Behaviour:
    return either(
        name,
        Check("Tipping?", lambda obs: bool(abs(obs[1] - body.lean) > TIPPING)),
        Act("Straighten up", lambda obs: balance(body, obs, 0.0)),
        Act("Lean forward", lambda obs: balance(body, obs, body.lean)),
    )


def hopper() -> py_trees.behaviour.Behaviour:
    """The tree above, for Hopper-v5."""
    return _stand("Stand (Hopper)", HOPPER)


def walker() -> py_trees.behaviour.Behaviour:
    """The tree above, for Walker2d-v5."""
    return _stand("Stand (Walker2d)", WALKER)
