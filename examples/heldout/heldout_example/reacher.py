"""Reacher-v5 (two joint torques in [-1, 1]): bring the fingertip to the target.

The observation is ``[cos q1, cos q2, sin q1, sin q2, target x, y, q1', q2', fingertip -
target x, y]``. The tree pulls the fingertip towards the target through the arm's Jacobian
(torque = K·Jᵀ·(target - tip) - D·q'), and only damps once it is there::

    [o] Reacher                     Selector, memory=False
        [-] Hold                    Sequence, memory=False
            --> On target?          |tip - target| < 1 cm
            --> Hold                torque = -D·q'
        --> Reach                   torque = K·Jᵀ·(target - tip) - D·q'

A fixed gain, no model of the arm's inertia: it overshoots and arrives slowly.
"""

from __future__ import annotations

import numpy as np
import py_trees

from heldout_example.leaves import Act, Check, either

LINKS = (0.1, 0.11)
"""The arm's two link lengths (m), from the MuJoCo model."""
K, D = 20.0, 0.1
"""Gain on the fingertip's error (torque per m through Jᵀ) and joint damping."""
ON_TARGET = 0.01
"""Distance (m) under which the arm only holds still."""


def _reach(obs: np.ndarray) -> np.ndarray:
    c1, c2, s1, s2 = obs[0], obs[1], obs[2], obs[3]
    c12, s12 = c1 * c2 - s1 * s2, s1 * c2 + c1 * s2
    l1, l2 = LINKS
    jacobian = np.array([[-l1 * s1 - l2 * s12, -l2 * s12], [l1 * c1 + l2 * c12, l2 * c12]])
    torque = K * jacobian.T @ -obs[8:10] - D * obs[6:8]
    return np.clip(torque, -1.0, 1.0).astype(np.float32)


def reach() -> py_trees.behaviour.Behaviour:
    """The tree above."""
    return either(
        "Reacher",
        Check("On target?", lambda obs: bool(np.hypot(obs[8], obs[9]) < ON_TARGET)),
        Act("Hold", lambda obs: np.clip(-D * obs[6:8], -1.0, 1.0).astype(np.float32)),
        Act("Reach", _reach),
    )
