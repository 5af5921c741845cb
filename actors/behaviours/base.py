"""The contract between an env actor (or the evaluator) and the policy it runs.

An env actor drives a behaviour like this::

    behaviour = builder.make_behaviour(num_actors)   # built by the launcher, pickled to Ray
    for each vectorised step:
        if new_weights := subscriber.poll():
            behaviour.load(new_weights)
        env_action, columns = behaviour.act(obs, rng, warmup=steps < warmup_steps)
        env.step(env_action)                 # the env clips; `columns` go to replay as is
        behaviour.end_episodes(terminated | truncated)

and the evaluator calls ``behaviour.load(weights)`` then ``behaviour.greedy(obs)``.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np

Columns = dict[str, np.ndarray]
"""Per-step replay columns a behaviour adds for a batch of B observations, each [B, ...]."""


class Behaviour(Protocol):
    """What every behaviour policy promises.

    ``act`` returns, besides the action the environment should apply, at least the
    columns ``action`` (the sampled action, UNCLIPPED: importance ratios are taken on
    it) and ``log_prob`` (its log-likelihood under this behaviour); ``columns()`` lists
    every column ``act`` returns, as a replay signature fragment.
    """

    def columns(self) -> dict[str, dict[str, Any]]:
        """Replay columns ``act`` returns: ``{name: {"dtype": ..., "shape": [...]}}``."""
        ...

    def load(self, weights: dict[str, Any]) -> None:
        """Adopts broadcast learner weights."""
        ...

    def act(
        self, obs: np.ndarray, rng: np.random.Generator, *, warmup: bool
    ) -> tuple[np.ndarray, Columns]:
        """Exploratory actions for a batch [B, obs_dim]; `warmup` selects the warm-up policy."""
        ...

    def end_episodes(self, ended: np.ndarray) -> None:
        """Told after each step which environments' episodes ended ([B] bool)."""
        ...

    def greedy(self, obs: np.ndarray) -> np.ndarray:
        """Deterministic actions for evaluation, [B, ...]."""
        ...

    def stats(self) -> dict[str, float]:
        """Scalars about the behaviour since the last call (e.g. option usage), then reset."""
        ...
