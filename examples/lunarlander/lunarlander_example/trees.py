"""A hard-coded lander for LunarLander-v3 with continuous actions, as a py_trees tree
(``lander``; ``lander_discrete`` is the same tree for the discrete actions).

The observation is ``[x, y, vx, vy, angle, angular velocity, left leg down, right leg
down]`` (x = 0 is the pad's centre) and the action ``[main, lateral]`` in [-1, 1]²: the
main engine fires for main > 0, a side engine for |lateral| > 0.5 (lateral < -0.5 turns
the lander counter-clockwise, towards a larger angle). The tree reads the observation from
graft's blackboard key ``/graft/observation`` and writes the action to ``/graft/action``::

    [o] Lander                      Selector, memory=False
        [-] Touched down            Sequence, memory=False
            --> Legs down?          both legs touch the ground
            --> Engines off         [-1, 0]
        [-] Tipping                 Sequence, memory=False
            --> Tipping?            |angle - lean| or |angular velocity| too large
            --> Right the lander    a side engine against the tilt, main engine off
        [-] Sinking                 Sequence, memory=False
            --> Sinking too fast?   vy below a speed that shrinks with the altitude
            --> Brake               main engine at a fixed throttle
        --> Coast                   engines off

The lean steers: it tilts the lander against its drift and its offset from the pad, so
that the main engine pushes it back. Every rule is a threshold with full-force (bang-bang)
answers, so the tree lands most of the time but wastes fuel and often touches down off the
pad or too hard: that is the room RL has.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import py_trees
from py_trees.common import Access, Status

NAMESPACE = "/graft"
"""graft writes the observation to /graft/observation and reads /graft/action."""

Observation = np.ndarray
"""[x, y, vx, vy, angle, angular velocity, left leg down, right leg down]."""

MAX_LEAN = 0.25
"""Largest lean (radians) the tree steers with."""
TIP_ANGLE = 0.15
"""How far (radians) the angle may stray from the lean before the tree rights it."""
TIP_SPIN = 0.3
"""Angular velocity (rad/s, as observed) the tree damps before anything else."""
THROTTLE = 1.0
"""Main engine command when braking (0 is 50 % power, 1 is full power)."""
SAFE_SINK = 0.1
"""Sink rate (as observed, -vy) the tree allows at the ground ..."""
SINK_PER_ALTITUDE = 0.5
"""... and how much faster it lets the lander fall per unit of altitude."""


def lean(obs: Observation) -> float:
    """The angle the lander should hold: tilted against its drift and its offset from
    the pad (a positive angle makes the main engine push towards -x)."""
    x, _, vx = obs[0], obs[1], obs[2]
    return float(np.clip(0.4 * x + 0.8 * vx, -MAX_LEAN, MAX_LEAN))


def tipping(obs: Observation) -> bool:
    return abs(obs[4] - lean(obs)) > TIP_ANGLE or abs(obs[5]) > TIP_SPIN


def sinking_too_fast(obs: Observation) -> bool:
    altitude, vy = obs[1], obs[3]
    return bool(vy < -(SAFE_SINK + SINK_PER_ALTITUDE * max(altitude, 0.0)))


def legs_down(obs: Observation) -> bool:
    return bool(obs[6] > 0.5 and obs[7] > 0.5)


class Check(py_trees.behaviour.Behaviour):
    """Condition: SUCCESS when ``test(observation)`` holds, else FAILURE."""

    def __init__(self, name: str, test: Callable[[Observation], bool]) -> None:
        super().__init__(name)
        self.test = test
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)

    def update(self) -> Status:
        return Status.SUCCESS if self.test(self.blackboard.observation) else Status.FAILURE


class Fire(py_trees.behaviour.Behaviour):
    """Action: writes ``command(observation)``, the engines' [main, lateral] (or, in the
    discrete tree, their action number)."""

    def __init__(self, name: str, command: Callable[[Observation], object]) -> None:
        super().__init__(name)
        self.command = command
        self.blackboard = self.attach_blackboard_client(name=name, namespace=NAMESPACE)
        self.blackboard.register_key("observation", access=Access.READ)
        self.blackboard.register_key("action", access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.action = self.command(self.blackboard.observation)
        return Status.SUCCESS


def right_the_lander(obs: Observation) -> list[float]:
    """Full side engine against the tilt and the spin; main engine off."""
    error = (lean(obs) - obs[4]) - 0.5 * obs[5]  # > 0: turn counter-clockwise
    return [-1.0, -1.0 if error > 0 else 1.0]


def _rule(
    name: str, test: Callable[[Observation], bool], act: Fire
) -> py_trees.behaviour.Behaviour:
    return py_trees.composites.Sequence(name, memory=False, children=[Check(f"{name}?", test), act])


def engines_off(obs: Observation) -> list[float]:
    return [-1.0, 0.0]


def brake(obs: Observation) -> list[float]:
    return [THROTTLE, 0.0]


Engines = Callable[[Callable[[Observation], list[float]]], Callable[[Observation], object]]
"""How a rule's [main, lateral] command becomes the action the tree writes."""


def _tree(engines: Engines) -> py_trees.behaviour.Behaviour:
    return py_trees.composites.Selector(
        "Lander",
        memory=False,
        children=[
            _rule("Touched down", legs_down, Fire("Engines off", engines(engines_off))),
            _rule("Tipping", tipping, Fire("Right the lander", engines(right_the_lander))),
            _rule("Sinking", sinking_too_fast, Fire("Brake", engines(brake))),
            Fire("Coast", engines(engines_off)),
        ],
    )


def lander() -> py_trees.behaviour.Behaviour:
    """The tree above (graft calls it once per process and ticks it once per observation)."""
    return _tree(lambda command: command)


def discrete_action(command: list[float]) -> int:
    """LunarLander's discrete action for a command [main, lateral]: 2 fires the main engine,
    1 and 3 the side engines that lateral < -0.5 and > 0.5 fire, 0 nothing (gymnasium's
    discrete engines are the continuous ones at full power)."""
    main, lateral = command
    if main > 0.0:
        return 2
    if abs(lateral) > 0.5:
        return 1 if lateral < 0.0 else 3
    return 0


def lander_discrete() -> py_trees.behaviour.Behaviour:
    """The same tree for LunarLander's discrete actions (``continuous: false``)."""
    return _tree(lambda command: lambda obs: discrete_action(command(obs)))
