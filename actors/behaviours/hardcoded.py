"""Hard-coded policies by environment: the backbones and demonstrators the methods improve."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

HardCodedPolicy = Callable[[np.ndarray], np.ndarray]
"""Batched deterministic policy: observations [B, obs_dim] -> actions [B, act_dim]."""


def hardcoded_policy(env_id: str) -> HardCodedPolicy:
    """Returns the hard-coded policy written for `env_id` (picklable, for Ray actors).

    Raises:
        ValueError: If no hard-coded policy exists for the environment.
    """
    if env_id == "Pendulum-v1":
        from actors.trees.pendulum import HardCodedPendulumPolicy

        return HardCodedPendulumPolicy()
    if env_id.endswith("MinecraftTravel-v0"):
        from actors.minecraft.agent.travel_env import TravelBackbone

        return TravelBackbone()
    raise ValueError(
        f"no hard-coded policy for {env_id!r}; the backbone, pre-training and options "
        "methods need one (known: Pendulum-v1, MinecraftTravel-v0)"
    )
