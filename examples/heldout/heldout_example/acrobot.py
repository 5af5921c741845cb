"""Acrobot-v1 (discrete torques -1, 0, +1 on the elbow): swing the tip above the bar.

The observation is ``[cos θ1, sin θ1, cos θ2, sin θ2, θ1', θ2']``. The tree pumps energy
into the swing: full torque in the direction the elbow already turns::

    [o] Acrobot                     Selector, memory=False
        [-] Push forward            Sequence, memory=False
            --> Elbow turning +?    θ2' > 0
            --> Push forward        action 2 (torque +1)
        --> Push back               action 0 (torque -1)

It never uses the zero torque and ignores where the links are, so some swings waste a
push against gravity: a mean of about -93 steps to the goal (min -246 over 20 episodes).
"""

from __future__ import annotations

import py_trees

from heldout_example.leaves import Act, Check, either

BACK, FORWARD = 0, 2
"""Acrobot-v1's actions for torque -1 and +1."""


def pump() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    return either(
        "Acrobot",
        Check("Elbow turning +?", lambda obs: bool(obs[5] > 0.0)),
        Act("Push forward", lambda obs: FORWARD),
        Act("Push back", lambda obs: BACK),
    )
