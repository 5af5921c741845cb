"""The learner loop drives an algorithm through its phases using only the contracts of
service/core.py. The contracts are implemented here in-process (a stream over batches
made up front, a publisher and an evaluator that record what they get); the Ray and
replay-server implementations run end to end in tests/graft."""

from __future__ import annotations

import time
from concurrent.futures import Future
from typing import Optional

import numpy as np
import pytest
import torch

from learner.agent import Phase
from learner.loop import LearnerLoop, Lockstep, LoopSettings, updates_allowed
from learner.selection import SelectionConfig
from service.core import Algorithm, Columns, EvalTag, Evaluation, Metrics, TensorBatch, Weights
from service.metrics import MetricsLogger, read_metric


class ListStream:
    """A `SampleStream` over fixed batches; each batch counts as one table insert."""

    def __init__(self, batches: list[Columns]) -> None:
        self.batches = iter(batches)
        self.wait_s = 0.0
        self.table_inserts = 0
        self.closed = False

    def next_within(self, timeout: Optional[float]) -> Columns:
        self.table_inserts += 1
        return next(self.batches)

    def close(self) -> None:
        self.closed = True


class CountingAlgorithm:
    """An `Algorithm` whose policy is its update count."""

    def __init__(self) -> None:
        self.updates = 0

    def update(self, batch: TensorBatch) -> Metrics:
        self.updates += 1
        return {"losses/x": float(batch["x"].sum())}

    def policy_state(self) -> Weights:
        return {"updates": torch.tensor(float(self.updates))}

    def state_dict(self) -> dict[str, int]:
        return {"updates": self.updates}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.updates = state["updates"]


class RecordingPublisher:
    def __init__(self) -> None:
        self.published: list[tuple[int, float]] = []

    def publish(self, version: int, weights: Weights) -> None:
        self.published.append((version, float(weights["updates"])))


class ImmediateEvaluator:
    """An `Evaluator` whose result is ready at once: the return is the policy's update count."""

    def evaluate(
        self, weights: Weights, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Future[Evaluation]:
        future: Future[Evaluation] = Future()
        value = float(weights["updates"])
        future.set_result({"tag": tag, "mean": value, "std": 0.0, "stats": {}})
        return future


def batches(phase: int, n: int) -> list[Columns]:
    """`n` batches of two items whose `phase` column says which phase's table they are from."""
    return [{"x": np.ones(2, np.float32), "phase": np.full(2, phase), "_key": np.zeros(2)}] * n


def test_each_phase_hands_its_batches_to_its_own_step_callable(tmp_path):
    demo_calls: list[tuple[Algorithm, TensorBatch]] = []

    def demo_step(algorithm: Algorithm, batch: TensorBatch) -> Metrics:
        demo_calls.append((algorithm, batch))
        return {}

    demos = Phase("demos", env_steps=0, updates=3, min_size=1, step=demo_step)
    online = Phase("online", env_steps=0, updates=4, min_size=1)  # the default step: update
    streams = {"demos": ListStream(batches(0, 3)), "online": ListStream(batches(1, 4))}
    algorithm, publisher = CountingAlgorithm(), RecordingPublisher()
    loop = LearnerLoop(
        algorithm,
        phases=[demos, online],
        open_stream=lambda phase: streams[phase.name],
        publisher=publisher,
        evaluator=ImmediateEvaluator(),
        logger=MetricsLogger(tmp_path, tensorboard=False),
        checkpoint_dir=tmp_path / "checkpoints",
        settings=LoopSettings(publish_every=2, eval_every=1, eval_episodes=1, checkpoint_every=5),
    )
    state = loop.run()

    assert [call[0] for call in demo_calls] == [algorithm] * 3
    assert all(set(batch) == {"x", "phase"} for _, batch in demo_calls)  # `_key` stays behind
    assert all(
        torch.equal(batch["phase"], torch.zeros(2, dtype=torch.int64)) for _, batch in demo_calls
    )
    assert algorithm.updates == 4  # the online phase's batches went to `update`
    assert state.updates == 7
    assert all(stream.closed for stream in streams.values())
    versions = [v for v, _ in publisher.published]
    assert versions == sorted(set(versions))  # versions only grow
    assert publisher.published[-1][1] == 4.0  # the final policy is published
    assert [e["tag"]["updates"] for e in state.evaluations] == sorted(
        e["tag"]["updates"] for e in state.evaluations
    )
    assert state.evaluations[-1]["mean"] == 4.0  # and evaluated


class StampingStream(ListStream):
    """Batches acted with version 0, stamped when they are sampled: an actor stuck on
    the first weights while the learner publishes after every update."""

    def next_within(self, timeout: Optional[float]) -> Columns:
        batch = super().next_within(timeout)
        return {
            **batch,
            "policy_version": np.zeros(2, np.int64),
            "acted_at": np.full(2, time.time()),
        }


def test_the_loop_logs_how_many_versions_behind_the_sampled_data_was_acted(tmp_path):
    online = Phase("online", env_steps=0, updates=4, min_size=1)
    logger = MetricsLogger(tmp_path, tensorboard=False)
    loop = LearnerLoop(
        CountingAlgorithm(),
        phases=[online],
        open_stream=lambda phase: StampingStream(batches(1, 4)),
        publisher=RecordingPublisher(),
        evaluator=ImmediateEvaluator(),
        logger=logger,
        checkpoint_dir=tmp_path / "checkpoints",
        settings=LoopSettings(
            publish_every=1, eval_every=100, eval_episodes=1, checkpoint_every=100, log_every=1
        ),
    )
    loop.run()
    logger.close()
    # Batch k is sampled after version k-1 was published; it was acted with version 0.
    _, lags = read_metric(logger.csv_path, "perf/policy_lag")
    assert lags == [0.0, 1.0, 2.0, 3.0]
    _, ages = read_metric(logger.csv_path, "perf/sample_age_versions")
    assert ages == [1.0, 2.0, 3.0, 4.0]  # the version after each update's publish


@pytest.mark.parametrize(
    "inserted, ratio, min_size, credit, expected",
    [
        (15, 2.0, 16, 0.0, 0),  # below min_size: nothing
        (16, 2.0, 16, 0.0, 0),  # at min_size, no credit: the first insert beyond it
        (17, 2.0, 16, 0.0, 1),  # 1 item x 2 samples per insert / batch 2
        (24, 2.0, 16, 0.0, 8),
        (24, 1.0, 16, 0.0, 4),  # half an update per env step
        (25, 1.0, 16, 0.0, 4),  # a half update is not one
        (16, 2.0, 16, 10.0, 5),  # a burn-in credit of 10 items = 5 updates at min_size
        (99, None, 16, 0.0, 0),  # no ratio: only once the actors have finished
    ],
)
def test_updates_allowed_is_the_rate_limiters_ratio(inserted, ratio, min_size, credit, expected):
    phase = Phase(
        "t", env_steps=100, updates=100, min_size=min_size, samples_per_insert=ratio,
        sample_credit=credit,
    )  # fmt: skip
    assert updates_allowed(phase, inserted, batch_size=2) == expected


class RecordingActors:
    """`LockstepActors` in-process: each call inserts 8 steps until `total`, and is logged."""

    def __init__(self, log: list[str], total: int) -> None:
        self.log, self.total, self.inserted = log, total, 0
        self.versions: list[int] = []

    def advance(self, table: str, version: int) -> int:
        steps = min(8, self.total - self.inserted)
        self.inserted += steps
        self.versions.append(version)
        self.log.append(f"insert {self.inserted}" if steps else "finished")
        return steps


class LoggingAlgorithm(CountingAlgorithm):
    def __init__(self, log: list[str]) -> None:
        super().__init__()
        self.log = log

    def update(self, batch: TensorBatch) -> Metrics:
        self.log.append("update")
        return super().update(batch)


def lockstep_loop(
    tmp_path, algorithm: Algorithm, phase: Phase, actors: RecordingActors
) -> LearnerLoop:
    return LearnerLoop(
        algorithm,
        phases=[phase],
        open_stream=lambda phase: ListStream(batches(0, phase.updates)),
        publisher=RecordingPublisher(),
        evaluator=ImmediateEvaluator(),
        logger=MetricsLogger(tmp_path, tensorboard=False, wall_clock=False),
        checkpoint_dir=tmp_path / "checkpoints",
        settings=LoopSettings(publish_every=8, eval_every=99, eval_episodes=1, checkpoint_every=99),
        lockstep=Lockstep(actors, batch_size=2),
    )


def test_lockstep_inserts_then_makes_exactly_the_updates_the_ratio_allows(tmp_path):
    log: list[str] = []
    # One update per env step (2 samples per insert, batch 2) past min_size 16.
    phase = Phase("t", env_steps=40, updates=24, min_size=16, samples_per_insert=2.0)
    actors = RecordingActors(log, total=40)
    loop = lockstep_loop(tmp_path, LoggingAlgorithm(log), phase, actors)
    state = loop.run()
    assert log == (
        ["insert 8", "insert 16", "insert 24"] + ["update"] * 8
        + ["insert 32"] + ["update"] * 8
        + ["insert 40"] + ["update"] * 8
    )  # fmt: skip
    assert (state.updates, state.env_steps) == (24, 40)
    # Weights published every 8 updates act from the next insert on.
    assert actors.versions == [0, 0, 0, 1, 2]
    # metrics.csv holds no wall-clock column.
    assert (tmp_path / "metrics.csv").read_text().splitlines()[0] == "env_steps,updates,key,value"


def test_lockstep_phase_without_a_ratio_updates_once_its_actors_finished(tmp_path):
    log: list[str] = []
    demos = Phase("demos", env_steps=20, updates=3, min_size=20, acts_with_weights=False)
    actors = RecordingActors(log, total=20)
    loop = lockstep_loop(tmp_path, LoggingAlgorithm(log), demos, actors)
    loop.run()
    assert log == ["insert 8", "insert 16", "insert 20", "finished"] + ["update"] * 3
    assert actors.versions == [-1] * 4  # the demonstrations need no weights


class FallingBackAlgorithm(CountingAlgorithm):
    """A `FallsBack` algorithm: its published weights say when they are the tree's."""

    def __init__(self) -> None:
        super().__init__()
        self.tree_only = False

    def policy_state(self) -> Weights:
        return {**super().policy_state(), "tree": torch.tensor(float(self.tree_only))}

    def tree_state(self) -> Weights:
        return {**super().policy_state(), "tree": torch.tensor(1.0)}

    def keep_tree(self) -> None:
        self.tree_only = True


class EpisodeEvaluator:
    """Per-episode returns: the tree scores 10 + i on episode i; the policy after `u`
    updates scores 10 + i + (u − 3), so it loses to the tree until its fourth update."""

    def __init__(self) -> None:
        self.asked: list[float] = []

    def evaluate(
        self, weights: Weights, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Future[Evaluation]:
        tree = float(weights["tree"]) == 1.0
        self.asked.append(-1.0 if tree else float(weights["updates"]))
        gain = 0.0 if tree else float(weights["updates"]) - 3.0
        returns = [10.0 + i + gain + 0.1 * (i % 2) for i in range(episodes)]
        future: Future[Evaluation] = Future()
        future.set_result(
            {
                "tag": tag,
                "mean": float(np.mean(returns)),
                "std": 0.0,
                "stats": {},
                "returns": returns,
            }  # fmt: skip
        )
        return future


def one_phase_loop(
    tmp_path, algorithm, evaluator, *, updates: int, settings: LoopSettings
) -> LearnerLoop:
    """A loop over one online phase of `updates` batches, logging to `tmp_path`."""
    return LearnerLoop(
        algorithm,
        phases=[Phase("online", env_steps=0, updates=updates, min_size=1)],
        open_stream=lambda phase: ListStream(batches(1, updates)),
        publisher=RecordingPublisher(),
        evaluator=evaluator,
        logger=MetricsLogger(tmp_path, tensorboard=False),
        checkpoint_dir=tmp_path / "checkpoints",
        settings=settings,
    )


def _guarded_loop(tmp_path, algorithm, evaluator, updates: int) -> LearnerLoop:
    settings = LoopSettings(
        publish_every=1, eval_every=1, eval_episodes=4, checkpoint_every=100,
        selection=SelectionConfig(episodes=4, z=1.0),
    )  # fmt: skip
    return one_phase_loop(tmp_path, algorithm, evaluator, updates=updates, settings=settings)


def test_every_in_run_evaluation_is_judged_against_the_tree_scored_once(tmp_path):
    algorithm, evaluator = FallingBackAlgorithm(), EpisodeEvaluator()
    loop = _guarded_loop(tmp_path, algorithm, evaluator, updates=6)
    state = loop.run()
    assert evaluator.asked.count(-1.0) == 2  # once for the in-run evaluations, once to select
    _, policy = read_metric(tmp_path / "metrics.csv", "eval/return_mean")
    steps, guarded = read_metric(tmp_path / "metrics.csv", "guard/return_mean")
    _, kept = read_metric(tmp_path / "metrics.csv", "guard/tree_kept")
    tree = 11.55  # the tree's mean over episodes 0-3
    # Below the tree (updates 0-3), the guarded score is the tree's; above, the policy's.
    assert len(guarded) == len(policy) >= 5
    for p, g, k in zip(policy, guarded, kept, strict=True):
        assert (g, k) == ((tree, 1.0) if p <= tree else (p, 0.0)), (p, g, k)
    assert min(guarded) == pytest.approx(tree)
    assert state.guard["tree_kept"] == 0.0 and not algorithm.tree_only  # 6 updates beat it


def test_a_run_stopped_early_keeps_the_tree_unless_its_last_evaluation_beat_it(tmp_path):
    early, evaluator = FallingBackAlgorithm(), EpisodeEvaluator()
    loop = _guarded_loop(tmp_path / "early", early, evaluator, updates=2)
    loop.run()  # with its final selection: 2 updates lose to the tree
    assert early.tree_only
    late = FallingBackAlgorithm()
    loop = _guarded_loop(tmp_path / "late", late, EpisodeEvaluator(), updates=6)
    loop.run()
    late.tree_only = False
    loop.keep_guarded()  # as a Ctrl-C does: the newest verdict (6 updates) was the policy
    assert not late.tree_only
    loop.state.guard["tree_kept"] = 1.0
    loop.keep_guarded()
    assert late.tree_only
