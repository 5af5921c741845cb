"""The captured update (learner/captured.py and each algorithm's captured.py): the same
numbers as the eager update over 50 updates, for every algorithm; one graph for
``torch.compile(fullgraph=True)`` on the CPU; on CUDA, capture, replay and no host sync.

Tolerance: after 50 updates every weight, target weight and Adam moment of the captured
learner is within 1e-5 + 1e-4 · |value| of the eager learner's (the two differ only in
rounding, e.g. Adam's rate as a float32 tensor: at the presets' own sizes the largest
weight difference measured was 6e-8 for pendulum-td3 and 8e-8 for cartpole-ddqn), and
the metrics it averaged on the device within 1e-4 relative of the mean of the eager ones.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from actors.transitions import replay_signature
from bench import learner_updates as bench
from graft.config import load_preset
from graft.registry import make_builder
from learner.captured import PACKED, DeviceMetrics
from learner.feed import Layout
from learner.loop import to_tensors
from service.core import Algorithm, Columns, Metrics

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="needs a CUDA device; torch sees none here")
UPDATES = 50
ROWS = {
    **bench.PRESETS,
    "options (Retrace)": "pendulum-options",
    "backbone_td3 standalone (IBRL)": "pendulum-backbone",
    "backbone_td3 standalone, standardized observations": "pendulum-backbone",
}
"""Every learner class: TD3, pre-training, backbone (with and without a teacher; a
standalone actor with the tree in the TD target, with standardized observations too),
Double DQN, options with intra-option learning and with Retrace (eq. 14)."""
_IBRL = {"backbone.residual": False, "backbone.tree_in_target": True}
ROW_SETTINGS = {
    "backbone_td3 standalone (IBRL)": _IBRL,
    "backbone_td3 standalone, standardized observations": {
        **_IBRL,
        "td3.standardize_observations": True,
    },
}
"""A row's settings beyond its preset's."""
SMALL = {"hidden_sizes": [32, 32], "batch_size": 32}
"""Networks and batches small enough for a quick test."""
ACTOR_NOW = {"td3.frozen_actor_updates": 0, "td3.policy_delay": 2}
"""TD3's actor trains from the first cycle (the presets freeze it for thousands)."""


def _setup(row: str, tmp: Path) -> tuple[Any, Any, Any]:
    """(builder, phase, config) of a row's preset, its actor training at once; the
    intra-option row without smoothing noise (its captured step draws noise for every
    pair of steps, the eager one for the kept pairs only: same generator, other draws)."""
    preset = ROWS[row]
    overrides: dict[str, Any] = {} if preset == "cartpole-ddqn" else dict(ACTOR_NOW)
    overrides.update(ROW_SETTINGS.get(row, {}))
    sections = [s for s in ("td3", "dqn") if getattr(load_preset(preset), s, None) is not None]
    overrides.update({f"{s}.{k}": v for s in sections for k, v in SMALL.items()})
    if preset == "pendulum-backbone-teacher":
        teacher = load_preset(preset, **overrides)
        overrides["backbone.teacher"] = bench._teacher(tmp / "teacher", teacher)
    if preset == "pendulum-options-residual":
        overrides["td3.policy_noise"] = 0.0
    config = load_preset(preset, **overrides)
    builder = make_builder(config)
    return builder, builder.phases()[0], config


def _batches(builder: Any, phase: Any, config: Any, count: int) -> Iterator[Columns]:
    env = config.make_env()
    signature = replay_signature(
        env.observation_space, builder.make_behaviour(num_actors=1).columns()
    )
    env.close()
    rng = np.random.default_rng(0)
    for _ in range(count):
        yield bench.random_batch(
            signature,
            batch=builder.batch_size,
            window=phase.sequence_length,
            actions=getattr(builder, "num_actions", 2),
            rng=rng,
        )


def _tensors(state: Any, prefix: str = "") -> Iterator[tuple[str, torch.Tensor]]:
    """Every float tensor of a (nested) state dict, by path."""
    items = state.items() if isinstance(state, dict) else enumerate(state)
    for key, value in items:
        if isinstance(value, dict | list):
            yield from _tensors(value, f"{prefix}{key}.")
        elif isinstance(value, torch.Tensor) and value.is_floating_point():
            yield f"{prefix}{key}", value


def _counters(state: Any, prefix: str = "") -> Iterator[tuple[str, int]]:
    for key, value in state.items():
        if isinstance(value, dict) and "optimizer" not in str(key):
            yield from _counters(value, f"{prefix}{key}.")
        elif isinstance(value, int | bool):
            yield f"{prefix}{key}", int(value)


def _assert_same_state(eager: Algorithm, captured: Algorithm) -> None:
    expected, got = eager.state_dict(), captured.state_dict()
    assert dict(_counters(got)) == dict(_counters(expected))
    want, have = dict(_tensors(expected)), dict(_tensors(got))
    assert want.keys() <= have.keys()
    for name, value in want.items():
        torch.testing.assert_close(
            have[name].cpu().to(value.dtype), value, atol=1e-5, rtol=1e-4, msg=name
        )


def _mean_metrics(history: list[Metrics]) -> dict[str, float]:
    names = {name for metrics in history for name in metrics}
    return {n: float(np.mean([m[n] for m in history if n in m])) for n in names}


def _run_both(row: str, tmp: Path, *, compiled: str | None, updates: int) -> None:
    builder, phase, config = _setup(row, tmp)
    eager, captured = builder.make_learner(), builder.make_learner()
    captured.capture(compiled=compiled)
    history = []
    for columns in _batches(builder, phase, config, updates):
        history.append(phase.step(eager, to_tensors(columns)))
        assert phase.step(captured, to_tensors(columns)) == {}  # no per-update metrics
    _assert_same_state(eager, captured)
    averaged = captured.read_metrics()
    expected = _mean_metrics(history)
    charts = {k for k in expected if k.startswith("charts/")}
    assert set(averaged) - charts == set(expected) - charts
    for name in set(expected) - charts:
        assert averaged[name] == pytest.approx(expected[name], rel=1e-4, abs=1e-6), name
    assert captured.read_metrics() == {}  # read once: the next window starts empty


@pytest.mark.parametrize("row", list(ROWS))
def test_captured_update_computes_what_the_eager_one_does(row: str, tmp_path: Path) -> None:
    _run_both(row, tmp_path, compiled=None, updates=UPDATES)


def test_captured_td3_cycle_traces_as_one_graph(tmp_path: Path) -> None:
    """``fullgraph=True`` refuses any graph break; the tracing backend checks the capture
    without generating kernels (the next test compiles them)."""
    _run_both("td3", tmp_path, compiled="eager", updates=6)


@pytest.mark.long
@pytest.mark.parametrize("row", list(ROWS))
def test_captured_update_compiled_whole_computes_what_the_eager_one_does(
    row: str, tmp_path: Path
) -> None:
    _run_both(row, tmp_path, compiled="inductor", updates=UPDATES)


def test_device_metrics_average_each_metric_over_the_updates_that_had_it() -> None:
    metrics = DeviceMetrics(torch.device("cpu"))
    metrics.add("a", torch.tensor(1.0))
    metrics.add("b", torch.tensor(5.0), torch.tensor(False))
    metrics.add("c", torch.tensor(float("nan")), torch.tensor(False))
    metrics.flush()
    metrics.add("a", torch.tensor(3.0))
    metrics.add("b", torch.tensor(7.0), torch.tensor(True))
    metrics.flush()
    assert metrics.read() == {"a": 2.0, "b": 7.0}
    assert metrics.read() == {}


def test_a_packed_batch_is_its_columns_at_their_offsets() -> None:
    rng = np.random.default_rng(1)
    batch = {
        "obs": rng.normal(size=(5, 3)).astype(np.float32),
        "action": rng.integers(0, 4, size=5),
        "terminated": rng.random(5) < 0.5,
        "_key": np.arange(5, dtype=np.uint64),  # a service column: left behind
    }
    layout = Layout.of(batch)
    packed = np.zeros(layout.nbytes, np.uint8)
    layout.pack(batch, packed)
    views = layout.views(torch.from_numpy(packed), with_packed=True)
    assert set(views) == {"obs", "action", "terminated", PACKED}
    for name in ("obs", "action", "terminated"):
        np.testing.assert_array_equal(views[name].numpy(), batch[name])


@needs_cuda
@pytest.mark.parametrize("row", list(ROWS))
def test_captured_update_on_cuda_replays_what_the_eager_cpu_update_computes(
    row: str, tmp_path: Path
) -> None:
    """Captured on CUDA (graphs replayed from the third cycle) against eager on the CPU;
    CUDA rounds differently, hence the wider tolerance."""
    builder, phase, config = _setup(row, tmp_path)
    eager = builder.make_learner()
    captured = builder.make_learner(device=torch.device("cuda", 0), compile="captured")
    for columns in _batches(builder, phase, config, UPDATES):
        phase.step(eager, to_tensors(columns))
        phase.step(captured, to_tensors(columns))
    want, have = dict(_tensors(eager.state_dict())), dict(_tensors(captured.state_dict()))
    for name, value in want.items():
        torch.testing.assert_close(have[name].cpu(), value, atol=1e-3, rtol=1e-2, msg=name)


@needs_cuda
@pytest.mark.parametrize("row", list(ROWS))
def test_captured_update_on_cuda_never_waits_for_the_device(row: str, tmp_path: Path) -> None:
    """After its warm-up and capture, an update fed by the pinned ring makes no host sync
    (``set_sync_debug_mode("error")`` raises on one)."""
    from learner.feed import PinnedRing

    builder, phase, config = _setup(row, tmp_path)
    learner = builder.make_learner(device=torch.device("cuda", 0), compile="captured")
    pool = list(_batches(builder, phase, config, 8))
    drawn = iter(range(10**6))
    feed = PinnedRing(
        lambda: pool[next(drawn) % len(pool)], device=torch.device("cuda", 0), group=4,
        packed=True,
    )  # fmt: skip
    for _ in range(12):  # warm-up, capture, the ring's buffers
        phase.step(learner, feed.next(left=10**6)[1])
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for _ in range(40):
            phase.step(learner, feed.next(left=10**6)[1])
    finally:
        torch.cuda.set_sync_debug_mode("default")
    assert learner.read_metrics()
