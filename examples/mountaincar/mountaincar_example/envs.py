"""MountainCarContinuous-v0 that reports, at each episode's end, whether the car reached the flag.

The episode terminates exactly when the car reaches the flag (position >= 0.45) and is
truncated after 999 steps otherwise. graft logs what the last step puts in
``info["episode_metrics"]`` as ``eval/<name>``: here ``eval/reached``, the fraction of
evaluation episodes that reached the flag.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym


class ReportReached(gym.Wrapper):
    """Adds ``episode_metrics: {reached: 0.0 or 1.0}`` to the info of an episode's last step."""

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            info = {**info, "episode_metrics": {"reached": float(terminated)}}
        return obs, reward, terminated, truncated, info


def mountain_car(**kwargs: Any) -> gym.Env:
    """gymnasium's MountainCarContinuous-v0 (``kwargs`` go to ``gym.make``), reporting
    whether each episode reached the flag."""
    return ReportReached(gym.make("MountainCarContinuous-v0", **kwargs))
