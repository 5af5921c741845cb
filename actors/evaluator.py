"""Ray actor that evaluates published policy weights with deterministic episodes."""

from __future__ import annotations

from concurrent.futures import Future
from typing import Any, Optional

import ray
import torch
from ray import ObjectRef

from actors.evaluation import run_episodes
from service.core import Behaviour, EvalTag, Evaluation, Weights


@ray.remote(num_cpus=0.25)
class Evaluator:
    """Runs `episodes` deterministic episodes of a behaviour's greedy policy (no exploration)."""

    def __init__(
        self,
        *,
        env_id: str,
        behaviour: Behaviour,
        seed: int,
        env_kwargs: Optional[dict[str, Any]] = None,
    ) -> None:
        torch.set_num_threads(1)
        self.env_id, self.seed, self.env_kwargs = env_id, seed, env_kwargs
        self.behaviour = behaviour

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Evaluation:
        """Returns mean and std of the episode returns, echoing `tag` back.

        `stats` carries what the behaviour counted while acting greedily (e.g. how often
        each option ran).
        """
        self.behaviour.load(weights)
        self.behaviour.stats()  # drop anything counted before these weights
        returns = run_episodes(
            self.behaviour.greedy,
            env_id=self.env_id,
            episodes=episodes,
            seed=self.seed,
            env_kwargs=self.env_kwargs,
        )
        return {
            "tag": tag,
            "mean": float(returns.mean()),
            "std": float(returns.std()),
            "stats": self.behaviour.stats(),
        }


class RemoteEvaluator:
    """The learner's `Evaluator` (service/core.py): an `Evaluator` Ray actor runs the episodes."""

    def __init__(
        self,
        *,
        env_id: str,
        behaviour: Behaviour,
        seed: int,
        env_kwargs: Optional[dict[str, Any]] = None,
    ) -> None:
        # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
        self._actor = Evaluator.remote(  # type: ignore[attr-defined]
            env_id=env_id, behaviour=behaviour, seed=seed, env_kwargs=env_kwargs
        )

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Future[Evaluation]:
        """Starts the episodes in the actor and returns at once."""
        ref: ObjectRef[Evaluation] = self._actor.evaluate.remote(
            weights, episodes=episodes, tag=tag
        )
        return ref.future()
