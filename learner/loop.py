"""The learner loop: sample from replay, update, publish weights, evaluate, checkpoint.

    stream = replay.sample_stream(table, batch_size)
    for batch in stream:                      # prefetched by a background thread
        metrics = algorithm.update(batch)
        every publish_every updates: broadcaster.publish(version + 1, weights)
        every eval_every env steps:  evaluator.evaluate(weights)   (asynchronous)
        every checkpoint_every:      save model + optimiser + counters
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Protocol

import numpy as np
import ray
import torch

from learner.checkpoint import save_checkpoint
from service.client import SampleStream
from service.metrics import MetricsLogger


class Algorithm(Protocol):
    """What the loop needs from a learning algorithm (TD3Learner satisfies it)."""

    num_updates: int

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]: ...
    def policy_state(self) -> dict[str, torch.Tensor]: ...
    def state_dict(self) -> dict[str, Any]: ...


def to_tensors(batch: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Service columns (`_key`, ...) stay behind; data columns become tensors.

    Decoded columns are read-only views of the received bytes, which torch cannot
    wrap safely, so each is copied once (microseconds for a batch).
    """
    return {k: torch.tensor(v) for k, v in batch.items() if not k.startswith("_")}


@dataclass
class LoopState:
    """Counters the loop reports and checkpoints."""

    updates: int = 0
    env_steps: int = 0
    version: int = 0
    wait_s: float = 0.0
    """Seconds spent waiting for a sampled batch after the first one (warm-up excluded)."""
    update_s: float = 0.0
    warmup_s: float = 0.0
    """Seconds until the first batch: the table filling to its minimum size."""
    evaluations: list[dict[str, Any]] = field(default_factory=list)


@dataclass(frozen=True)
class LoopSettings:
    """When the loop publishes, evaluates, logs and checkpoints."""

    total_updates: int
    publish_every: int
    eval_every: int
    eval_episodes: int
    checkpoint_every: int
    log_every: int = 250


class LearnerLoop:
    """Drives one algorithm from a sample stream until `total_updates`."""

    def __init__(
        self,
        algorithm: Algorithm,
        *,
        stream: SampleStream,
        broadcaster: Any,
        evaluator: Any,
        logger: MetricsLogger,
        checkpoint_dir: Path,
        settings: LoopSettings,
        state: Optional[LoopState] = None,
        on_progress: Optional[Callable[[LoopState], None]] = None,
    ) -> None:
        self.algorithm = algorithm
        self.stream = stream
        self.broadcaster = broadcaster
        self.evaluator = evaluator
        self.logger = logger
        self.checkpoint_dir = checkpoint_dir
        self.settings = settings
        self.state = state or LoopState()
        self.on_progress = on_progress
        self._pending_evals: list[Any] = []
        # A resumed run starts a fresh table: its insert counter restarts at zero.
        self._env_steps_offset = self.state.env_steps
        self._next_eval = (self.state.env_steps // settings.eval_every + 1) * settings.eval_every

    def publish(self) -> dict[str, torch.Tensor]:
        """Broadcasts the current policy under the next version number."""
        weights = self.algorithm.policy_state()
        self.state.version += 1 if self.state.updates else 0
        ray.get(self.broadcaster.publish.remote(self.state.version, [ray.put(weights)]))
        return weights

    def _evaluate(self, weights: dict[str, torch.Tensor]) -> None:
        tag = {"env_steps": self.state.env_steps, "updates": self.state.updates}
        self._pending_evals.append(
            self.evaluator.evaluate.remote(weights, episodes=self.settings.eval_episodes, tag=tag)
        )

    def _collect_evaluations(self, wait: bool = False) -> None:
        if not self._pending_evals:
            return
        ready, self._pending_evals = ray.wait(
            self._pending_evals,
            num_returns=len(self._pending_evals) if wait else 1,
            timeout=None if wait else 0,
        )
        for result in ray.get(ready):
            self.state.evaluations.append(result)
            tag = result["tag"]
            self.logger.log(
                {"eval/return_mean": result["mean"], "eval/return_std": result["std"]},
                env_steps=tag["env_steps"],
                updates=tag["updates"],
            )

    def checkpoint(self) -> Path:
        s = self.state
        return save_checkpoint(
            self.checkpoint_dir,
            {
                "algorithm": self.algorithm.state_dict(),
                "loop": {"updates": s.updates, "env_steps": s.env_steps, "version": s.version},
            },
            updates=s.updates,
        )

    def run(self) -> LoopState:
        s, cfg = self.state, self.settings
        weights = self.publish()
        window_start, window_updates = time.perf_counter(), 0
        first_batch = True
        while s.updates < cfg.total_updates:
            wait_before = self.stream.wait_s
            batch = next(self.stream)
            waited = self.stream.wait_s - wait_before
            if first_batch:
                s.warmup_s, first_batch = waited, False  # filling to min_size is not starvation
            else:
                s.wait_s += waited
            s.env_steps = self._env_steps_offset + self.stream.table_inserts
            t = time.perf_counter()
            metrics = self.algorithm.update(to_tensors(batch))
            s.update_s += time.perf_counter() - t
            s.updates += 1
            window_updates += 1
            if s.updates % cfg.publish_every == 0:
                weights = self.publish()
            if s.env_steps >= self._next_eval:
                self._evaluate(weights)
                self._next_eval = (s.env_steps // cfg.eval_every + 1) * cfg.eval_every
            self._collect_evaluations()
            if s.updates % cfg.log_every == 0:
                elapsed = time.perf_counter() - window_start
                metrics["perf/updates_per_s"] = window_updates / elapsed
                metrics["perf/learner_wait_fraction"] = s.wait_s / max(
                    s.wait_s + s.update_s, 1e-9
                )
                self.logger.log(metrics, env_steps=s.env_steps, updates=s.updates)
                window_start, window_updates = time.perf_counter(), 0
            if s.updates % cfg.checkpoint_every == 0:
                self.checkpoint()
            if self.on_progress is not None:
                self.on_progress(s)
        weights = self.publish()
        self._evaluate(weights)  # the final policy is always evaluated
        self._collect_evaluations(wait=True)
        self.checkpoint()
        return s
