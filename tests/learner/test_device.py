"""learner/device.py: the device a learner runs on, the batches moved there, checkpoints
that load on any device, and compiled updates that equal eager ones.

Every test runs on the CPU through the same code a GPU run takes; the ones that need a
GPU are parametrised or marked to skip (with the reason) where torch sees none.
"""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from graft.config import load_preset
from graft.registry import make_builder
from learner.checkpoint import load_checkpoint, save_checkpoint
from learner.device import CPU, BatchFeed, learned_from, resolve_compile, resolve_device
from learner.device_spec import check_compile_mode, check_device_spec
from learner.loop import to_tensors
from learner.td3.learning import TD3Learner
from tests.learner.helpers import ACT_DIM, HIGH, LOW, OBS_DIM, SMALL, flat_params, td3_batch

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="needs a CUDA device; torch sees none here")
DEVICES = ["cpu", pytest.param("cuda", marks=needs_cuda)]

_spec = importlib.util.spec_from_file_location(
    "bench_learner", Path(__file__).parents[2] / "bench" / "learner_updates.py"
)
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


@pytest.mark.parametrize("spec", ["auto", "cpu", "cuda", "cuda:0", "cuda:3"])
def test_device_spellings_are_accepted(spec: str) -> None:
    check_device_spec(spec)


@pytest.mark.parametrize("spec", ["gpu", "CPU", "cuda:", "cuda:x", "mps", ""])
def test_other_device_spellings_are_refused_naming_what_is_allowed(spec: str) -> None:
    with pytest.raises(ValueError, match=r"must be auto, cpu, cuda or cuda:N"):
        check_device_spec(spec)


def test_compile_modes_are_checked() -> None:
    for mode in ("off", "auto", "compile", "cuda_graphs"):
        check_compile_mode(mode)
    with pytest.raises(ValueError, match="compile='fast' must be one of off, auto"):
        check_compile_mode("fast")


def test_auto_picks_cuda_where_visible_and_the_cpu_elsewhere() -> None:
    expected = torch.device("cuda", 0) if CUDA else CPU
    assert resolve_device("auto") == expected
    assert resolve_device("cpu") == CPU


@pytest.mark.skipif(CUDA, reason="the refusal is for a machine without CUDA; this one has it")
@pytest.mark.parametrize("spec", ["cuda", "cuda:1"])
def test_cuda_asked_for_without_cuda_is_refused_in_one_line(spec: str) -> None:
    with pytest.raises(ValueError) as refused:
        resolve_device(spec)
    message = str(refused.value)
    assert message.startswith(f"learner.device={spec}: this process sees 0 CUDA device(s)")
    assert "learner.device=auto or cpu" in message and "\n" not in message


def test_compile_auto_is_captured_on_cuda_and_eager_on_the_cpu() -> None:
    assert resolve_compile("auto", CPU) == "off"
    assert resolve_compile("compile", CPU) == "compile"
    assert resolve_compile("auto", torch.device("cuda", 0)) == "captured"
    assert resolve_compile("captured", torch.device("cuda", 0)) == "captured"
    for mode in ("cuda_graphs", "captured"):
        with pytest.raises(ValueError, match=f"compile={mode} needs a CUDA device"):
            resolve_compile(mode, CPU)


# One preset per learner class: TD3, pre-training, backbone (with and without a teacher),
# Double DQN and options.
PRESETS = list(bench.PRESETS.values())


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("preset", PRESETS)
def test_every_learner_trains_on_the_device_it_is_given_and_publishes_cpu_weights(
    preset: str, device: str, tmp_path: Path
) -> None:
    overrides: dict[str, object] = {"td3.hidden_sizes": [16, 16], "dqn.hidden_sizes": [16, 16]}
    if preset == "pendulum-backbone-teacher":
        teacher = load_preset(preset, **overrides)
        overrides["backbone.teacher"] = bench._teacher(tmp_path / "teacher", teacher)
    config = load_preset(preset, **overrides)
    builder = make_builder(config)
    learner = builder.make_learner(device=torch.device(device))
    phase = builder.phases()[0]
    env = config.make_env()
    signature = bench.replay_signature(
        env.observation_space, builder.make_behaviour(num_actors=1).columns()
    )
    env.close()
    rng = np.random.default_rng(0)
    batch = bench.random_batch(
        signature,
        batch=8,
        window=phase.sequence_length,
        actions=getattr(builder, "num_actions", 2),
        rng=rng,
    )
    feed = BatchFeed(lambda: batch, device=torch.device(device), depth=2, to_tensors=to_tensors)
    for _ in range(3):
        _, tensors = feed.next(left=3)
        metrics = phase.step(learner, tensors)
        assert all(np.isfinite(v) for v in metrics.values())
    assert all(v.device.type == "cpu" for v in learner.policy_state().values())
    # A checkpoint of this learner loads into a CPU learner of the same preset.
    path = save_checkpoint(tmp_path / "run", {"algorithm": learner.state_dict()}, updates=3)
    on_cpu = builder.make_learner(device=CPU)
    on_cpu.load_state_dict(load_checkpoint(path)["algorithm"])
    published, loaded = learner.policy_state(), on_cpu.policy_state()
    assert all(torch.equal(published[k], loaded[k]) for k in published)


def test_batch_feed_on_the_cpu_draws_each_batch_when_its_update_needs_it() -> None:
    drawn: list[int] = []

    def draw() -> dict[str, np.ndarray]:
        drawn.append(len(drawn))
        return {"x": np.full(2, len(drawn) - 1, np.float32), "_key": np.zeros(2, np.int64)}

    feed = BatchFeed(draw, device=CPU, depth=4, to_tensors=to_tensors)
    for i in range(3):
        columns, tensors = feed.next(left=10)
        assert len(drawn) == i + 1 and feed.in_flight() == 0  # nothing drawn ahead on a CPU
        assert set(tensors) == {"x"} and tensors["x"].tolist() == [i, i]
        assert not tensors["x"].is_pinned() if CUDA else True


@needs_cuda
def test_batch_feed_on_cuda_copies_ahead_in_order_and_never_past_the_phase() -> None:
    device = torch.device("cuda", 0)
    drawn: list[int] = []

    def draw() -> dict[str, np.ndarray]:
        drawn.append(len(drawn))
        return {"x": np.full(1000, len(drawn) - 1, np.float32)}

    feed = BatchFeed(draw, device=device, depth=2, to_tensors=to_tensors)
    left = 5
    for i in range(5):
        _, tensors = feed.next(left=left)
        left -= 1
        assert tensors["x"].device == device and float(tensors["x"].sum()) == 1000 * i
        assert feed.in_flight() == min(2, left)
    assert len(drawn) == 5  # none drawn past the phase's last update


def _gpu_style_checkpoint(path: Path, learner: TD3Learner, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A checkpoint as a CUDA learner writes it: storages tagged cuda:0 and a CUDA
    generator's 16-byte state. (Without a GPU only the tags can stand in for one.)"""
    state = dict(learner.state_dict(), noise_rng=torch.arange(16, dtype=torch.uint8))
    with monkeypatch.context() as patch:
        patch.setattr(torch.serialization, "location_tag", lambda storage: "cuda:0")
        return save_checkpoint(path, {"algorithm": state}, updates=3)


@pytest.mark.skipif(CUDA, reason="shows the refusal a CPU-only machine gives; this one has CUDA")
def test_a_checkpoint_written_on_a_gpu_resumes_on_a_cpu_only_machine(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trained = TD3Learner(OBS_DIM, ACT_DIM, LOW, HIGH, config=SMALL, seed=0)
    for i in range(3):
        trained.update(td3_batch(seed=i))
    path = _gpu_style_checkpoint(tmp_path, trained, monkeypatch)
    with pytest.raises(RuntimeError, match="CUDA"):
        torch.load(path, weights_only=False)  # without map_location: the GPU is missing
    runs = []
    for _ in range(2):
        resumed = TD3Learner(OBS_DIM, ACT_DIM, LOW, HIGH, config=SMALL, seed=1)
        resumed.load_state_dict(load_checkpoint(path)["algorithm"])
        assert torch.equal(flat_params(resumed.critic), flat_params(trained.critic))
        resumed.update(td3_batch(seed=3))
        runs.append(flat_params(resumed.critic))
    # The CUDA noise state reseeds the CPU generator: a resumed run is still repeatable.
    assert torch.equal(runs[0], runs[1])


@needs_cuda
@pytest.mark.parametrize(("trained_on", "resumed_on"), [("cuda", "cpu"), ("cpu", "cuda")])
def test_a_checkpoint_resumes_on_the_other_device(
    trained_on: str, resumed_on: str, tmp_path: Path
) -> None:
    trained = TD3Learner(OBS_DIM, ACT_DIM, LOW, HIGH, config=SMALL, seed=0, device=trained_on)
    for i in range(3):
        trained.update(td3_batch(seed=i))
    path = save_checkpoint(tmp_path, {"algorithm": trained.state_dict()}, updates=3)
    resumed = TD3Learner(OBS_DIM, ACT_DIM, LOW, HIGH, config=SMALL, seed=1, device=resumed_on)
    resumed.load_state_dict(load_checkpoint(path)["algorithm"])
    assert torch.equal(flat_params(resumed.actor).cpu(), flat_params(trained.actor).cpu())
    metrics = resumed.update(td3_batch(seed=3))
    assert all(np.isfinite(v) for v in metrics.values())


COMPILED_TOLERANCE = 1e-5
"""Largest difference allowed between compiled and eager weights after a few updates
(float32; the compiled kernels may fuse and reorder sums)."""


@pytest.mark.long  # torch.compile on the CPU: a C++ build of the kernels, minutes here
@pytest.mark.parametrize(
    ("device", "mode"),
    [
        ("cpu", "compile"),
        *[pytest.param("cuda", m, marks=needs_cuda) for m in ("compile", "cuda_graphs")],
    ],
)
def test_a_compiled_update_equals_the_eager_one(device: str, mode: str) -> None:
    config = dataclasses.replace(SMALL, policy_delay=2)

    def train(compile: str) -> tuple[list[torch.Tensor], list[dict[str, float]]]:
        learner = TD3Learner(
            OBS_DIM, ACT_DIM, LOW, HIGH, config=config, seed=0, device=device, compile=compile
        )
        metrics = [learner.update(td3_batch(seed=i)) for i in range(4)]
        nets = (learner.actor, learner.critic, learner.target_actor, learner.target_critic)
        return [flat_params(n).cpu() for n in nets], metrics

    eager, eager_metrics = train("off")
    compiled, compiled_metrics = train(mode)
    for a, b in zip(eager, compiled, strict=True):
        assert torch.allclose(a, b, atol=COMPILED_TOLERANCE, rtol=0)
    for a, b in zip(eager_metrics, compiled_metrics, strict=True):
        assert a.keys() == b.keys()
        assert all(abs(a[k] - b[k]) <= COMPILED_TOLERANCE * max(1, abs(a[k])) for k in a)


def test_the_learner_takes_the_data_columns_and_which_window_steps_are_valid():
    columns = {
        "obs": np.zeros((2, 3, 1), np.float32),
        "_key": np.zeros((2, 3), np.uint64),
        "_weight": np.ones(2, np.float32),
        "_valid": np.array([[True, True, False], [True, True, True]]),
    }
    tensors = to_tensors(columns)
    assert set(tensors) == {"obs", "_valid"}
    assert tensors["_valid"].tolist() == [[True, True, False], [True, True, True]]
    # The pinned copies a GPU learner takes choose by the same rule.
    assert [c for c in columns if learned_from(c)] == ["obs", "_valid"]
