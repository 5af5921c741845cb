"""The learner loop drives an algorithm through its phases using only the contracts of
service/core.py. The contracts are implemented here in-process (a stream over batches
made up front, a publisher and an evaluator that record what they get); the Ray and
replay-server implementations run end to end in tests/service/run."""

from __future__ import annotations

import time
from concurrent.futures import Future
from typing import Optional

import numpy as np
import torch

from learner.agent import Phase
from learner.loop import LearnerLoop, LoopSettings
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

    def evaluate(self, weights: Weights, *, episodes: int, tag: EvalTag) -> Future[Evaluation]:
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
