"""LunarLander-v3 that reports, at each episode's end, whether the lander landed.

gymnasium ends an episode with a reward of exactly -100 when the lander crashes or flies
off the screen, and exactly +100 when it comes to rest; graft logs what the last step puts
in ``info["episode_metrics"]`` as ``eval/<name>``: here ``eval/landed``, the fraction of
evaluation episodes that came to rest (truncated after 1,000 steps counts as not landed).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym

LANDED_REWARD = 100.0
"""LunarLander's reward on the step where the lander comes to rest."""


class ReportLanded(gym.Wrapper):
    """Adds ``episode_metrics: {landed: 0.0 or 1.0}`` to the info of an episode's last step."""

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            landed = terminated and float(reward) == LANDED_REWARD
            info = {**info, "episode_metrics": {"landed": float(landed)}}
        return obs, reward, terminated, truncated, info


def lunar_lander(**kwargs: Any) -> gym.Env:
    """gymnasium's LunarLander-v3 (``kwargs`` go to ``gym.make``, e.g. ``continuous=True``),
    reporting whether each episode landed."""
    return ReportLanded(gym.make("LunarLander-v3", **kwargs))
