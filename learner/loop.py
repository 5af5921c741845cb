"""The learner loop: sample from replay, update, publish weights, evaluate, checkpoint.

`LearnerLoop.run`, in outline::

    for phase in phases:                       # e.g. pre-training on demos, then online
        stream = open_stream(phase)            # ReplayClient.sample_stream, prefetching
        for each of the phase's `updates` batches:
            metrics = phase.step(algorithm, to_tensors(stream.next_within(STALL_CHECK_S)))
            every publish_every updates: publisher.publish(version, algorithm.policy_state())
            every eval_every env steps:  evaluator.evaluate(weights, ...)  (a future)
            every log_every updates:     log metrics, perf/policy_lag from the batch
            every checkpoint_every:      self.checkpoint()  (model, optimiser, counters)
        evaluate at the end of every phase
    with a final selection: score the policy and the tree alone, keep the better (`_select`);
    with best_in_run the best in-run evaluation's policy is scored too

In reproducible mode (a `Lockstep`) the loop also drives the actors: before each update
it has the actors insert, one batch at a time in a fixed order, until the phase's held
ratio admits that update (`updates_allowed`); batches are drawn only when needed, and each
evaluation is logged as soon as it is done.
"""

from __future__ import annotations

import concurrent.futures
import copy
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Protocol, runtime_checkable

import torch

from learner.agent import Phase
from learner.captured import ReadsMetrics
from learner.checkpoint import save_checkpoint
from learner.device import CPU, learned_from
from learner.feed import make_feed
from learner.lockstep import Lockstep as Lockstep  # re-exported: the run builds one
from learner.lockstep import LockstepFeed
from learner.lockstep import updates_allowed as updates_allowed  # re-exported
from learner.selection import SelectionConfig, choose, tree_wins
from service.core import (
    Algorithm,
    Columns,
    EvalTag,
    Evaluation,
    Evaluator,
    SampleStream,
    TensorBatch,
    WeightPublisher,
    Weights,
)
from service.metrics import MetricsLogger, PolicyLag

STALL_CHECK_S = 10.0
"""Seconds without a sampled batch before the loop asks its watchdog what is wrong."""
UNSELECTED = "unselected"
"""RUN/UNSELECTED/ckpt-*.pt: the final policy, when the selection kept an earlier one
(best_in_run), for comparing the two (`graft eval RUN/unselected/ckpt-….pt`)."""


def to_tensors(batch: Columns) -> TensorBatch:
    """The learned-from columns (`learned_from`) become tensors; `_key`, ... stay behind.

    Decoded columns are read-only views of the received bytes, which torch cannot
    wrap safely, so each is copied once: by numpy, then wrapped (8 µs for a TD3 batch of
    256, against 29 µs through `torch.tensor`).
    """
    return {k: torch.from_numpy(v.copy()) for k, v in batch.items() if learned_from(k)}


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
    evaluations: list[Evaluation] = field(default_factory=list)
    selection: dict[str, float] = field(default_factory=dict)
    """The final selection's scores (``policy``, ``tree``) and ``tree_kept`` (1 or 0); with
    an earlier policy as a candidate (best_in_run) also its score ``best``, the env steps it
    was evaluated at ``best_env_steps``, ``best_kept``, and ``policy_alone_kept``: whether
    the final policy alone, tested at the uncorrected z, would have been kept."""
    guard: dict[str, float] = field(default_factory=dict)
    """The newest in-run evaluation judged against the tree (`LearnerLoop` with a
    selection): ``policy``, ``tree`` and ``tree_kept`` (1: a run stopped there plays the
    tree)."""


@runtime_checkable
class FallsBack(Protocol):
    """An algorithm whose greedy policy can fall back to the hard-coded one."""

    tree_only: bool
    """The greedy policy is the tree alone (`keep_tree` was called)."""

    def tree_state(self) -> Weights:
        """Published weights under which the greedy policy is the tree alone."""

    def keep_tree(self) -> None:
        """From now on the greedy policy (published and checkpointed) is the tree alone."""


@dataclass(frozen=True)
class LoopSettings:
    """When the loop publishes, evaluates, logs and checkpoints."""

    publish_every: int
    eval_every: int
    eval_episodes: int
    checkpoint_every: int
    keep_checkpoints: int = 3
    log_every: int = 250
    selection: SelectionConfig = SelectionConfig()


class LearnerLoop:
    """Drives one algorithm through its phases, each from its own sample stream."""

    def __init__(
        self,
        algorithm: Algorithm,
        *,
        phases: list[Phase],
        open_stream: Callable[[Phase], SampleStream],
        publisher: WeightPublisher,
        evaluator: Evaluator,
        logger: MetricsLogger,
        checkpoint_dir: Path,
        settings: LoopSettings,
        state: Optional[LoopState] = None,
        on_progress: Optional[Callable[[LoopState], None]] = None,
        watchdog: Optional[Callable[[], None]] = None,
        lockstep: Optional[Lockstep] = None,
        env_steps_offset: Optional[int] = None,
        device: torch.device = CPU,
        prefetch_to_device: int = 0,
    ) -> None:
        """`device` is where the algorithm computes; on CUDA `prefetch_to_device` batches
        beyond the current one are copied there ahead of their update (none in lock-step,
        which draws each batch only once the actors have made it allowed)."""
        self.algorithm = algorithm
        self.phases = phases
        self.open_stream = open_stream
        self.publisher = publisher
        self.evaluator = evaluator
        self.logger = logger
        self.checkpoint_dir = checkpoint_dir
        self.settings = settings
        self.state = state or LoopState()
        self.on_progress = on_progress
        self.watchdog = watchdog
        """Called while no batch arrives; raises if the data can never come."""
        self.lockstep = lockstep
        self.device = device
        self.prefetch_to_device = 0 if lockstep is not None else prefetch_to_device
        self._pending_evals: list[Future[Evaluation]] = []
        self._tree_eval: Optional[Future[Evaluation]] = None
        """The tree alone on the in-run evaluation's episodes (the same every time)."""
        self._states: dict[Future[Evaluation], tuple[Weights, dict[str, Any]]] = {}
        """With best_in_run: the weights and learner state each pending evaluation scores."""
        self._best: Optional[tuple[Evaluation, Weights, dict[str, Any]]] = None
        """With best_in_run: the best in-run evaluation so far, its weights and state."""
        # The run's env steps when the table was empty: a table refilled on resume counts
        # from zero (offset: the checkpoint's env steps), a restored one goes on counting.
        self._env_steps_offset = (
            self.state.env_steps if env_steps_offset is None else env_steps_offset
        )
        self._started = time.perf_counter()
        self._published = False
        self._lag = PolicyLag()
        self._next_eval = (self.state.env_steps // settings.eval_every + 1) * settings.eval_every

    def publish(self) -> Weights:
        """Publishes the current policy under the next version number."""
        weights = self.algorithm.policy_state()
        self.state.version += 1 if self.state.updates else 0
        self._published = True
        self._lag.published(self.state.version, time.time())
        self.publisher.publish(self.state.version, weights)
        return weights

    def _evaluate(self, weights: Weights) -> None:
        tag: EvalTag = {
            "env_steps": self.state.env_steps,
            "updates": self.state.updates,
            "wall_s": time.perf_counter() - self._started,
        }
        episodes = self.settings.eval_episodes
        future = self.evaluator.evaluate(weights, episodes=episodes, tag=tag)
        self._pending_evals.append(future)
        if self.settings.selection.best_in_run:  # copies: training goes on meanwhile
            state = copy.deepcopy(self.algorithm.state_dict())
            self._states[future] = ({k: v.clone() for k, v in weights.items()}, state)
        if self._guarded is not None and self._tree_eval is None:
            self._tree_eval = self.evaluator.evaluate(
                self._guarded.tree_state(), episodes=episodes, tag=tag
            )

    @property
    def _guarded(self) -> Optional[FallsBack]:
        """The algorithm, when every in-run evaluation is also judged against the tree: a
        run with a final selection, whose evaluations have a spread to test (≥ 2)."""
        if self.settings.selection.episodes and self.settings.eval_episodes >= 2:
            return self.algorithm if isinstance(self.algorithm, FallsBack) else None
        return None

    def _collect_evaluations(self, wait: bool = False) -> None:
        """Logs the evaluations that have finished (with `wait`, all of them), in order;
        each judged against the tree once the tree's own evaluation is in."""
        if wait:
            tree = [self._tree_eval] if self._tree_eval is not None else []
            concurrent.futures.wait(self._pending_evals + tree)
        pending, self._pending_evals = self._pending_evals, []
        tree_waits = self._tree_eval is not None and not self._tree_eval.done()
        for future in pending:
            if not future.done() or tree_waits:
                self._pending_evals.append(future)
                continue
            result = future.result()
            self.state.evaluations.append(result)
            self._offer(future, result)
            tag = result["tag"]
            scalars = {"eval/return_mean": result["mean"], "eval/return_std": result["std"]}
            scalars.update({f"eval/{k}": v for k, v in result.get("stats", {}).items()})
            if self._tree_eval is not None:
                scalars.update(self._guard(result, self._tree_eval.result()))
            self.logger.log(scalars, env_steps=tag["env_steps"], updates=tag["updates"])

    def _offer(self, future: Future[Evaluation], result: Evaluation) -> None:
        """With best_in_run: the policy `future` scored becomes the best in-run one if its
        score beats every earlier one's."""
        kept = self._states.pop(future, None)
        if kept is not None and (self._best is None or result["mean"] > self._best[0]["mean"]):
            self._best = (result, *kept)

    def _guard(self, policy: Evaluation, tree: Evaluation) -> dict[str, float]:
        """The final selection's paired test applied to an in-run evaluation: what a run
        stopped here plays (``guard/return_mean``: the policy's score if it beat the tree,
        else the tree's) and whether that is the tree (``guard/tree_kept``)."""
        kept = tree_wins(policy.get("returns", []), tree.get("returns", []),
                         z=self.settings.selection.z)  # fmt: skip
        self.state.guard = {
            "policy": policy["mean"],
            "tree": tree["mean"],
            "tree_kept": float(kept),
        }
        return {
            "guard/return_mean": tree["mean"] if kept else policy["mean"],
            "guard/tree_kept": float(kept),
        }

    def keep_guarded(self) -> None:
        """For a run stopped before its end (Ctrl-C): its policy from now on is the tree
        unless the newest in-run evaluation showed the policy beating it."""
        algorithm = self._guarded
        if algorithm is not None and self.state.guard.get("tree_kept", 1.0):
            algorithm.keep_tree()

    def checkpoint(self) -> Path:
        s = self.state
        return save_checkpoint(
            self.checkpoint_dir,
            {
                "algorithm": self.algorithm.state_dict(),
                "loop": {"updates": s.updates, "env_steps": s.env_steps, "version": s.version},
            },
            updates=s.updates,
            keep=self.settings.keep_checkpoints,
        )

    def run(self) -> LoopState:
        """Runs every phase to its update count; the state's `updates` count across phases.

        A resumed run (state.updates > 0) resumes inside the phase its counter falls in.
        """
        s = self.state
        done_before, weights = 0, None
        for phase in self.phases:
            end = done_before + phase.updates
            if s.updates < end:
                if phase.acts_with_weights and not self._published:
                    weights = self.publish()  # actors wait for these before acting
                weights = self._run_phase(phase, end, weights)
            done_before = end
            self._env_steps_offset = max(self._env_steps_offset, s.env_steps)
        weights = self.publish()
        self._evaluate(weights)  # the final policy is always evaluated
        self._collect_evaluations(wait=True)
        if self.settings.selection.episodes and isinstance(self.algorithm, FallsBack):
            self._select(weights, self.algorithm)
        self.checkpoint()
        return s

    def _select(self, weights: Weights, algorithm: FallsBack) -> None:
        """Scores the final policy, the tree alone and, with best_in_run, the best in-run
        evaluation's policy on the evaluator's episodes (the training side's, never a
        benchmark's held-out ones); keeps the tree unless a policy beat it (`choose`)."""
        c, s = self.settings.selection, self.state
        candidates = {"policy": weights}
        if self._best is not None and self._best[0]["tag"]["updates"] != s.updates:
            candidates["best"] = self._best[1]  # an earlier policy than the final one
        first = self.settings.eval_episodes if c.best_in_run else 0
        tag: EvalTag = {"env_steps": s.env_steps, "updates": s.updates, "wall_s": 0.0}
        scored = {
            name: self.evaluator.evaluate(w, episodes=c.episodes, tag=tag, first=first)
            for name, w in {**candidates, "tree": algorithm.tree_state()}.items()
        }
        results = {name: future.result() for name, future in scored.items()}
        returns = {name: result.get("returns", []) for name, result in results.items()}
        tree = returns.pop("tree")
        chosen = choose(returns, tree, z=c.z)
        if chosen == "best" and self._best is not None:
            final = {"algorithm": self.algorithm.state_dict()}
            save_checkpoint(self.checkpoint_dir.parent / UNSELECTED, final, updates=s.updates)
            self.algorithm.load_state_dict(self._best[2])
        elif chosen is None:
            algorithm.keep_tree()
        if chosen != "policy":
            self.publish()
        s.selection = {
            "policy": results["policy"]["mean"],
            "tree": results["tree"]["mean"],
            "tree_kept": float(chosen is None),
        }
        if "best" in candidates and self._best is not None:
            alone = not tree_wins(returns["policy"], tree, z=c.z)
            s.selection |= {
                "best": results["best"]["mean"],
                "best_env_steps": float(self._best[0]["tag"]["env_steps"]),
                "best_kept": float(chosen == "best"),
                "policy_alone_kept": float(alone),
            }
        self.logger.log(
            {f"select/{k}": v for k, v in s.selection.items()},
            env_steps=s.env_steps,
            updates=s.updates,
        )

    def _next_batch(self, stream: SampleStream) -> Columns:
        """Waits for a batch, asking the watchdog every few seconds whether the actors
        that should produce it are still alive (a dead actor raises instead of a hang)."""
        while True:
            try:
                return stream.next_within(STALL_CHECK_S)
            except TimeoutError:
                if self.watchdog is not None:
                    self.watchdog()

    def _run_phase(self, phase: Phase, end: int, weights: Optional[Weights]) -> Optional[Weights]:
        s, cfg = self.state, self.settings
        stream = self.open_stream(phase)
        offset = self._env_steps_offset
        window_start, window_updates = time.perf_counter(), 0
        first_batch = True
        feed = (
            None if self.lockstep is None else LockstepFeed(self.lockstep, phase, first=s.updates)
        )
        batches = make_feed(
            lambda: self._next_batch(stream),
            device=self.device,
            depth=self.prefetch_to_device,
            to_tensors=to_tensors,
            packed=isinstance(self.algorithm, ReadsMetrics) and self.algorithm.captures,
        )
        try:
            while s.updates < end:
                if feed is not None:
                    s.env_steps = offset + feed.until_allowed(s.updates + 1, s.version)
                wait_before, drawing = stream.wait_s, time.perf_counter()
                batch, tensors = batches.next(left=end - s.updates)
                waited = stream.wait_s - wait_before
                # Making tensors of the batch (and copying it to the device) is update work.
                s.update_s += max(time.perf_counter() - drawing - waited, 0.0)
                if first_batch:
                    s.warmup_s += waited  # filling to min_size is not starvation
                    first_batch = False
                else:
                    s.wait_s += waited
                if feed is None:
                    s.env_steps = offset + stream.table_inserts
                t = time.perf_counter()
                metrics = phase.step(self.algorithm, tensors)
                s.update_s += time.perf_counter() - t
                s.updates += 1
                window_updates += 1
                if self._published and s.updates % cfg.publish_every == 0:
                    weights = self.publish()
                if self._published and weights is not None and s.env_steps >= self._next_eval:
                    self._evaluate(weights)
                    self._next_eval = (s.env_steps // cfg.eval_every + 1) * cfg.eval_every
                # Reproducible mode logs an evaluation right away: its row's place in
                # metrics.csv must not depend on how long the episodes took.
                self._collect_evaluations(wait=feed is not None)
                if s.updates % cfg.log_every == 0:
                    if isinstance(self.algorithm, ReadsMetrics):  # captured: summed on device
                        metrics = {**self.algorithm.read_metrics(), **metrics}
                    elapsed = time.perf_counter() - window_start
                    metrics["perf/updates_per_s"] = window_updates / elapsed
                    metrics["perf/learner_wait_fraction"] = s.wait_s / max(
                        s.wait_s + s.update_s, 1e-9
                    )
                    metrics.update(self._lag.measure(batch, version=s.version, now=time.time()))
                    self.logger.log(metrics, env_steps=s.env_steps, updates=s.updates)
                    window_start, window_updates = time.perf_counter(), 0
                if s.updates % cfg.checkpoint_every == 0:
                    self.checkpoint()
                if self.on_progress is not None:
                    self.on_progress(s)
        finally:
            stream.close()
        if phase is not self.phases[-1]:
            # The policy at the end of a phase (e.g. right after pre-training) is a point
            # on the curve: evaluate it before the next phase changes it.
            weights = self.publish() if self._published else self.algorithm.policy_state()
            self._evaluate(weights)
        return weights
