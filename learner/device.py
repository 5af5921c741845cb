"""Where the learner computes: the device it resolves to, the fast update it may compile,
and the batches moved onto that device ahead of their update.

A preset's ``learner`` section names them (``device: auto | cpu | cuda | cuda:N``,
``compile: off | auto | compile | cuda_graphs``, ``prefetch_to_device``); the run resolves
them once, before anything starts (`resolve_device`, `resolve_compile`), and hands the
results to the builder's ``make_learner(device=..., compile=...)`` and to `BatchFeed`.
On the CPU every piece is the plain path: no pinned memory, no copies ahead, eager
networks and the default (for-each) Adam, so a CPU run computes what it always did.
"""

from __future__ import annotations

import collections
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, Optional

import numpy as np
import torch
from torch import nn

from learner.device_spec import CompileMode, check_compile_mode, check_device_spec
from service.core import Columns, TensorBatch

CPU = torch.device("cpu")


def resolve_device(spec: str) -> torch.device:
    """The device ``learner.device`` names on this machine: ``auto`` is the first CUDA
    device when one is visible, else the CPU.

    Raises:
        ValueError: a CUDA device was asked for and this process sees none (or fewer), in
            one line naming the field, the value and what is allowed.
    """
    check_device_spec(spec)
    if spec == "auto":
        return torch.device("cuda", 0) if torch.cuda.is_available() else CPU
    device = torch.device(spec)
    if device.type != "cuda":
        return device
    visible = torch.cuda.device_count() if torch.cuda.is_available() else 0
    index = device.index or 0
    if index >= visible:
        build = f"CUDA {torch.version.cuda}" if torch.version.cuda else "a CPU-only build"
        raise ValueError(
            f"learner.device={spec}: this process sees {visible} CUDA device(s) (torch "
            f"{torch.__version__}, {build}); use learner.device=auto or cpu here, or place "
            "the learner on a GPU node (learner.num_gpus: 1)"
        )
    return torch.device("cuda", index)


def device_name(device: torch.device) -> str:
    """What the device is, in words: the GPU's name, or the CPU's model."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform

    return platform.processor() or platform.machine() or "cpu"


def resolve_compile(mode: str, device: torch.device) -> CompileMode:
    """The compile mode ``learner.compile`` means on `device`: ``auto`` is the captured
    update (`learner.captured`: each update one CUDA graph, no host sync) on CUDA, and eager
    on the CPU, where a run computes what it always did. (Compiling only the networks'
    forward passes left each update a few dozen small kernels launched from Python: TD3 on
    an H200 made 227 updates/s compiled, 267 eager and 282 as CUDA graphs;
    bench/learner_updates.py --device cuda.)

    Raises:
        ValueError: ``cuda_graphs`` or ``captured`` on a device that is not CUDA.
    """
    check_compile_mode(mode)
    if mode == "auto":
        return "captured" if device.type == "cuda" else "off"
    if mode in ("cuda_graphs", "captured") and device.type != "cuda":
        raise ValueError(
            f"learner.compile={mode} needs a CUDA device, the learner runs on {device}; "
            "use compile, auto or off"
        )
    modes: dict[str, CompileMode] = {
        "off": "off",
        "compile": "compile",
        "cuda_graphs": "cuda_graphs",
        "captured": "captured",
    }
    return modes[mode]


def compile_networks(modules: Iterable[nn.Module], mode: CompileMode) -> None:
    """Compiles each module's forward in place (`nn.Module.compile`: parameters, state-dict
    keys and checkpoints stay as they are); ``cuda_graphs`` replays them as CUDA graphs
    (torch.compile's reduce-overhead mode). ``off`` leaves them eager, and so does
    ``captured``, whose update is captured whole instead."""
    if mode in ("off", "captured"):
        return
    options = {"mode": "reduce-overhead"} if mode == "cuda_graphs" else {}
    for module in modules:
        module.compile(**options)


class Adam:
    """Adam, fused into one kernel on CUDA; on the CPU the default for-each Adam (the fused
    CPU kernel rounds differently, which would change every CPU run's numbers). Built at
    its first use: building a torch optimiser imports torch._dynamo (1.2 s of CPU), which a
    learner built only to act (`graft eval`, `graft.load_policy`) never needs. A state
    loaded before then is loaded into it when it is built, so the optimiser is the one it
    always was."""

    def __init__(self, params: Iterable[nn.Parameter], *, lr: float, device: torch.device) -> None:
        self._params = list(params)
        self._lr = lr
        self._fused = True if device.type == "cuda" else None
        self._built: Optional[torch.optim.Adam] = None
        self._loaded: Optional[dict[str, Any]] = None

    @property
    def optimizer(self) -> torch.optim.Adam:
        """The torch optimiser (built now if it was not)."""
        if self._built is None:
            self._built = torch.optim.Adam(self._params, lr=self._lr, fused=self._fused)
            if self._loaded is not None:
                self._built.load_state_dict(self._loaded)
                self._loaded = None
        return self._built

    @property
    def param_groups(self) -> list[dict[str, Any]]:
        return self.optimizer.param_groups

    def zero_grad(self, set_to_none: bool = True) -> None:
        self.optimizer.zero_grad(set_to_none=set_to_none)

    def step(self) -> None:
        self.optimizer.step()

    def state_dict(self) -> dict[str, Any]:
        return self.optimizer.state_dict()

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if self._built is None:
            self._loaded = state
        else:
            self._built.load_state_dict(state)


VALID = "_valid"
"""The one service column a learner reads: which steps of sampled windows [B, k] are their
episode's (after an episode's end, replay repeats its last step to fill the window)."""


def learned_from(column: str) -> bool:
    """Data columns and `VALID`; the other service columns (`_key`, `_weight`, ...) stay
    behind."""
    return not column.startswith("_") or column == VALID


def pinned_tensors(batch: Columns) -> TensorBatch:
    """The learned-from columns copied once into pinned (page-locked) host memory, from
    which a non-blocking copy to the GPU runs while the GPU computes."""
    return {k: _pinned(v) for k, v in batch.items() if learned_from(k)}


def _pinned(array: np.ndarray) -> torch.Tensor:
    """`array` copied once into pinned memory. (`torch.tensor(array, pin_memory=True)` is
    refused, "Can't pin tensor constructed from numpy", torch 2.11 on an H200; and a
    decoded batch's arrays are read-only views of its message, which `torch.as_tensor`
    warns of.)"""
    dtype = torch.from_numpy(np.empty(0, array.dtype)).dtype
    pinned = torch.empty(array.shape, dtype=dtype, pin_memory=True)
    pinned.numpy()[...] = array
    return pinned


class BatchFeed:
    """Sampled batches, each on the learner's device by the time its update starts.

    On CUDA it keeps up to `depth` batches beyond the current one in flight: drawn from
    the stream, pinned, and copied on a side stream while the update before them runs.
    On the CPU (or with depth 0) each batch is drawn when its update needs it and becomes
    tensors where it is (`to_tensors`), exactly as without a feed.
    """

    def __init__(
        self,
        draw: Callable[[], Columns],
        *,
        device: torch.device,
        depth: int,
        to_tensors: Callable[[Columns], TensorBatch],
    ) -> None:
        """`draw` returns the next sampled batch (waiting for it); `to_tensors` is the CPU
        conversion."""
        if depth < 0:
            raise ValueError(f"depth={depth} must be >= 0")
        self.draw, self.device, self.to_tensors = draw, device, to_tensors
        self.on_cuda = device.type == "cuda"
        self.depth = depth if self.on_cuda else 0
        self._copies: Optional[torch.cuda.Stream] = (
            torch.cuda.Stream(device=device) if self.on_cuda else None
        )
        self._ahead: collections.deque[tuple[Columns, TensorBatch, Optional[torch.cuda.Event]]]
        self._ahead = collections.deque()

    def next(self, *, left: int) -> tuple[Columns, TensorBatch]:
        """The next batch, as drawn and as tensors on the device; `left` (>= 1) is how many
        batches the phase still needs, so that nothing is drawn past its end."""
        if not self._ahead:
            self._ahead.append(self._start(self.draw()))
        columns, tensors, ready = self._ahead.popleft()
        # Start the next batches' copies before this batch's update is queued behind them.
        while len(self._ahead) < min(self.depth, left - 1):
            self._ahead.append(self._start(self.draw()))
        if ready is not None:
            torch.cuda.current_stream(self.device).wait_event(ready)
            for tensor in tensors.values():  # the allocator must not reuse it too early
                tensor.record_stream(torch.cuda.current_stream(self.device))
        return columns, tensors

    def _start(self, columns: Columns) -> tuple[Columns, TensorBatch, Optional[torch.cuda.Event]]:
        if not self.on_cuda:
            return columns, self.to_tensors(columns), None
        assert self._copies is not None
        pinned = pinned_tensors(columns)
        with torch.cuda.stream(self._copies):
            tensors = {k: v.to(self.device, non_blocking=True) for k, v in pinned.items()}
            ready = torch.cuda.Event()
            ready.record(self._copies)
        return columns, tensors, ready

    def in_flight(self) -> int:
        """Batches drawn ahead and not yet handed out."""
        return len(self._ahead)
