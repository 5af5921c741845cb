"""The spaces each method handles, and the one-line refusal naming the space when it cannot.

Every method observes a flat (1-D) Box; any other observation space (Dict, Tuple, an
image) reaches it through the preset's ``obs_wrapper``. TD3 and the methods built on it
act in a bounded 1-D Box, Double DQN in a Discrete space.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

FLATTEN_HINT = "e.g. obs_wrapper: gymnasium.wrappers:FlattenObservation"


def observation_dim(space: spaces.Space, method: str) -> int:
    """The size of a flat Box observation space.

    Raises:
        ValueError: Any other space; the message names it and the wrapper setting.
    """
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ValueError(
            f"{method} needs a flat (1-D) Box observation space, the environment's is "
            f"{space}: set obs_wrapper to a wrapper that flattens or encodes it "
            f"({FLATTEN_HINT})"
        )
    return int(space.shape[0])


def box_action_dim(space: spaces.Space, method: str) -> int:
    """The size of a bounded 1-D Box action space (continuous actions).

    Raises:
        ValueError: A discrete or unbounded space; the message names it and what to use.
    """
    if isinstance(space, spaces.Discrete):
        raise ValueError(
            f"{method} needs continuous actions (a 1-D Box), the environment's action space "
            f"is {space}: use algorithm ddqn for discrete actions (dqn.warmup: hardcoded "
            "starts it from your hard-coded policy)"
        )
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise ValueError(f"{method} needs a 1-D Box action space, the environment's is {space}")
    if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
        raise ValueError(
            f"{method} needs finite action bounds, the environment's action space is {space}: "
            "wrap it to a bounded box (gymnasium.wrappers.RescaleAction or ClipAction)"
        )
    return int(space.shape[0])


def discrete_actions(space: spaces.Space, method: str) -> int:
    """The number of actions of a Discrete action space.

    Raises:
        ValueError: Any other space; the message names it and what to use.
    """
    if not isinstance(space, spaces.Discrete):
        raise ValueError(
            f"{method} needs a Discrete action space, the environment's is {space}: use a "
            "TD3-family algorithm (td3, backbone_td3, pretrain_td3, options) for continuous "
            "actions"
        )
    return int(space.n)
