"""The pieces of a captured update: one step function of tensors only, run as one CUDA
graph on a GPU (or compiled whole by ``torch.compile(fullgraph=True)``), that leaves no
host sync behind.

A step function takes a dict of static input tensors and changes the learner in place:
its gradients come from `torch.autograd.grad`, its optimisers step with `DeviceAdam`
(capturable, fused on CUDA, learning rate and step count on the device), its smoothing
noise comes from a `NoiseSource` (a seeded generator drawn from inside the graph) and its
metrics are summed on the device by `DeviceMetrics`, read once per log interval.
`StepGraph` runs it: on CUDA one eager warm-up call, then a capture, then replays fed by
one copy per batch; on the CPU eagerly, or compiled whole.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from typing import Optional, Protocol, runtime_checkable

import torch
from torch.optim.adam import adam

StepFn = Callable[[dict[str, torch.Tensor]], None]
"""A step function: static input tensors in, the learner changed in place."""
PACKED = "_packed"
"""A batch's columns as one flat byte tensor (the ring feed's): its columns are views of
it, so one copy moves the whole batch."""

_SOURCES: dict[int, torch.Generator] = {}
_ids = itertools.count()


@torch.library.custom_op("graft::normal_like", mutates_args=("draws",))
def _normal_like(like: torch.Tensor, draws: torch.Tensor, source: int) -> torch.Tensor:
    """N(0, 1) noise shaped like `like`, from the registered generator `source`; counts the
    draw in `draws` (a mutated input, which keeps the draws in program order)."""
    draws.add_(1)
    return torch.randn(like.shape, generator=_SOURCES[source], dtype=like.dtype, device=like.device)


@_normal_like.register_fake
def _(like: torch.Tensor, draws: torch.Tensor, source: int) -> torch.Tensor:
    return torch.empty_like(like)


class NoiseSource:
    """A seeded generator that a captured step draws from. ``torch.compile`` cannot trace a
    `torch.Generator` argument, so the draw is one opaque op (``graft::normal_like``) that
    calls `torch.randn` with it: compiled or eager, the noise is the generator's own
    stream, the same numbers as the eager learner's. A CUDA graph registers the generator
    (`generators`), so each replay draws fresh noise."""

    def __init__(self, generator: torch.Generator, device: torch.device) -> None:
        self.generator = generator
        self.id = next(_ids)
        _SOURCES[self.id] = generator
        self.draws = torch.zeros((), dtype=torch.int64, device=device)
        """Draws so far (on the device: counting costs no sync)."""

    def normal_like(self, like: torch.Tensor) -> torch.Tensor:
        return _normal_like(like, self.draws, self.id)

    def __del__(self) -> None:
        _SOURCES.pop(self.id, None)


def tracing() -> AbstractContextManager[None]:
    """What ``torch.compile`` needs to trace a step function whole: `torch.autograd.grad`
    traced into the graph instead of a graph break."""
    import torch._dynamo.config

    return torch._dynamo.config.patch(trace_autograd_ops=True)  # type: ignore[no-any-return]


class DeviceAdam:
    """Steps a torch Adam's parameters with its own state tensors, as a captured step needs:
    ``capturable`` (the step count on the device), fused on CUDA, the learning rate a
    device tensor (`lr`, which a step function may overwrite in place). The state stays the
    optimiser's, so its `state_dict` (and every checkpoint) is the one it always was."""

    def __init__(self, optimizer: torch.optim.Adam, *, device: torch.device) -> None:
        (group,) = optimizer.param_groups
        self.params: list[torch.Tensor] = list(group["params"])
        self.betas: tuple[float, float] = group["betas"]
        self.eps: float = group["eps"]
        self.lr = torch.tensor(float(group["lr"]), dtype=torch.float32, device=device)
        self.on_cuda = device.type == "cuda"
        for p in self.params:
            state = optimizer.state[p]
            if not state:
                state["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                state["step"] = torch.zeros((), dtype=torch.float32)
            state["step"] = state["step"].to(device=device, dtype=torch.float32)
        self.exp_avgs = [optimizer.state[p]["exp_avg"] for p in self.params]
        self.exp_avg_sqs = [optimizer.state[p]["exp_avg_sq"] for p in self.params]
        self.steps = [optimizer.state[p]["step"] for p in self.params]

    @torch.no_grad()
    def step(self, grads: Sequence[torch.Tensor], enabled: Optional[torch.Tensor] = None) -> None:
        """One Adam step on `grads`; with `enabled` (a device bool) parameters and state
        change only where it is true, so that the step needs no branch on the host."""
        kept = None
        if enabled is not None:
            kept = [t.clone() for t in (*self.params, *self.exp_avgs, *self.exp_avg_sqs)]
            kept += [s.clone() for s in self.steps]
        # Capturable needs the step on the device: CUDA, or a graph being compiled (the
        # CPU's eager Adam refuses the flag, and runs the single-tensor path instead).
        capturable = self.on_cuda or torch.compiler.is_compiling()
        adam(
            self.params,
            list(grads),
            self.exp_avgs,
            self.exp_avg_sqs,
            [],
            self.steps,
            foreach=capturable and not self.on_cuda,
            fused=True if self.on_cuda else None,
            capturable=capturable,
            lr=self.lr,
            beta1=self.betas[0],
            beta2=self.betas[1],
            weight_decay=0.0,
            eps=self.eps,
            maximize=False,
            amsgrad=False,
            grad_scale=None,
            found_inf=None,
            differentiable=False,
            has_complex=False,
        )
        if enabled is not None and kept is not None:
            live = [*self.params, *self.exp_avgs, *self.exp_avg_sqs, *self.steps]
            for now, before in zip(live, kept, strict=True):
                now.copy_(torch.where(enabled, now, before))


@runtime_checkable
class ReadsMetrics(Protocol):
    """An algorithm whose updates may sum their metrics on the device (a captured update
    returns none of its own, so that no update waits for the device)."""

    @property
    def captures(self) -> bool:
        """Updates run as captured steps."""

    def read_metrics(self) -> dict[str, float]:
        """The metrics since the last read, averaged; none when each update returned its own."""


class DeviceMetrics:
    """Metrics summed on the device, each with its count; `read` moves them all to the host
    in one transfer (the only sync) and starts the next window.

    A step function `add`s its metrics; `collect` (at the step's end) stacks them into one
    tensor the step returns, and `accumulate` adds that to the sums outside the step: a
    compiled step's in-place changes reach only its inputs, not tensors it merely reads.
    """

    def __init__(self, device: torch.device) -> None:
        self.device = device
        self._pending: list[tuple[str, torch.Tensor, Optional[torch.Tensor]]] = []
        self.names: tuple[str, ...] = ()
        """The names of the last `collect`, in its order."""
        self._windows: dict[tuple[str, ...], torch.Tensor] = {}

    def add(self, name: str, value: torch.Tensor, weight: Optional[torch.Tensor] = None) -> None:
        """Adds `value` (a scalar) to `name`'s window; `weight` (a device bool) counts it
        only where true."""
        self._pending.append((name, value.detach().to(torch.float64), weight))

    def collect(self) -> Optional[torch.Tensor]:
        """[sums, counts] of the metrics added since the last collect (None: none were)."""
        pending, self._pending = self._pending, []
        if not pending:
            return None
        self.names = tuple(name for name, _, _ in pending)
        # A step without rows may have a NaN mean (0 / 0): it must not reach the sum.
        sums = [v if w is None else torch.where(w, v, 0.0) for _, v, w in pending]
        counts = [torch.ones_like(v) if w is None else w.to(v.dtype) for _, v, w in pending]
        return torch.stack([torch.stack(sums), torch.stack(counts)])

    def accumulate(self, names: tuple[str, ...], collected: torch.Tensor) -> None:
        """Adds a step's `collect`ed metrics (of `names`) to the window."""
        if names not in self._windows:
            self._windows[names] = torch.zeros_like(collected)
        self._windows[names].add_(collected)

    def flush(self) -> None:
        """Accumulates what was added outside a step function (an eager step)."""
        collected = self.collect()
        if collected is not None:
            self.accumulate(self.names, collected)

    def read(self) -> dict[str, float]:
        """The mean of each metric over its window (those counted at least once)."""
        if not self._windows:
            return {}
        keys = list(self._windows)
        values = torch.cat([self._windows[k] for k in keys], dim=1).tolist()
        for window in self._windows.values():
            window.zero_()
        sums: dict[str, float] = {}
        counts: dict[str, float] = {}
        names = [name for key in keys for name in key]
        for name, total, count in zip(names, values[0], values[1], strict=True):
            sums[name] = sums.get(name, 0.0) + total
            counts[name] = counts.get(name, 0.0) + count
        return {n: sums[n] / counts[n] for n in sums if counts[n] > 0}


class StepGraph:
    """One step function over static inputs, loaded batch by batch (`load`) and run
    (`run`). On CUDA: `load` copies each batch into static buffers (one copy when it comes
    packed); the first run is eager (on a side stream, as capture needs: allocations and
    lazy state happen there), the second captures one CUDA graph, and every run after it
    replays the graph. On the CPU: `load` keeps the tensors, and the step runs eagerly, or
    compiled whole (``torch.compile(fullgraph=True, backend=compiled)``: ``inductor``, or
    ``eager`` to check only that it traces as one graph) from its second run on. The
    metrics the step adds to `metrics` are its outputs, accumulated after each run."""

    def __init__(
        self,
        fn: StepFn,
        *,
        device: torch.device,
        metrics: Sequence[DeviceMetrics],
        sources: Sequence[NoiseSource] = (),
        compiled: Optional[str] = None,
    ) -> None:
        self.step, self.device, self.sources = fn, device, list(sources)
        self.metrics = list(metrics)
        self._names: list[tuple[str, ...]] = []
        self._outputs: list[Optional[torch.Tensor]] = []
        self.on_cuda = device.type == "cuda"
        self.runs = 0
        self.inputs: dict[str, torch.Tensor] = {}
        """The static inputs (on CUDA; on the CPU the last batches loaded)."""
        self._graph: Optional[torch.cuda.CUDAGraph] = None
        self._run = self.fn
        if compiled is not None and not self.on_cuda:
            with tracing():
                self._run = torch.compile(self.fn, fullgraph=True, backend=compiled)

    def fn(self, inputs: dict[str, torch.Tensor]) -> list[Optional[torch.Tensor]]:
        """The step, returning each of `metrics`' collected metrics."""
        self.step(inputs)
        return [m.collect() for m in self.metrics]

    def _accumulate(self, outputs: list[Optional[torch.Tensor]]) -> None:
        if not self._names:  # the first run is eager: its names are every run's
            self._names = [m.names for m in self.metrics]
        for m, names, out in zip(self.metrics, self._names, outputs, strict=True):
            if out is not None:
                m.accumulate(names, out)

    def load(self, prefix: str, batch: dict[str, torch.Tensor]) -> None:
        """`batch`'s columns as inputs ``prefix + column``."""
        named = {prefix + k: v for k, v in batch.items()}
        if not self.on_cuda:
            self.inputs.update(named)
        elif not all(k in self.inputs for k in named):
            self.inputs.update(static_copies({k: v.to(self.device) for k, v in named.items()}))
        else:
            fill(self.inputs, named)

    def run(self) -> None:
        """One step on the loaded inputs."""
        self.runs += 1
        if not self.on_cuda:
            with tracing():
                self._accumulate((self.fn if self.runs == 1 else self._run)(self.inputs))
            return
        if self.runs == 1:
            side = torch.cuda.Stream(self.device)
            side.wait_stream(torch.cuda.current_stream(self.device))
            with torch.cuda.stream(side):
                outputs = self.fn(self.inputs)
            torch.cuda.current_stream(self.device).wait_stream(side)
            self._accumulate(outputs)
            return
        if self._graph is None:
            graph = torch.cuda.CUDAGraph()
            for source in self.sources:
                graph.register_generator_state(source.generator)
            with torch.cuda.graph(graph):
                self._outputs = self.fn(self.inputs)
            self._graph = graph
        self._graph.replay()
        self._accumulate(self._outputs)


def fill(static: dict[str, torch.Tensor], named: dict[str, torch.Tensor]) -> None:
    """`named` copied into the static buffers: one copy for a packed batch (its columns
    are views of its packed bytes, on both sides), else one per column."""
    packed = [k for k in named if k.endswith(PACKED)]
    done: set[str] = set()
    for key in packed:
        static[key].copy_(named[key], non_blocking=True)
        prefix = key[: -len(PACKED)]
        done |= {k for k in named if k[: k.rfind("/") + 1] == prefix}
    for key, value in named.items():
        if key not in done:
            static[key].copy_(value, non_blocking=True)


def static_copies(inputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Copies of `inputs` to capture with; a packed batch's columns stay views of its packed
    copy, at the same byte offsets, so that one copy refills them all."""
    static = {k: v.clone() for k, v in inputs.items() if k.endswith(PACKED)}
    for key, value in inputs.items():
        if key in static:
            continue
        packed = key[: key.rfind("/") + 1] + PACKED
        if packed not in static or not value.is_contiguous():
            static[key] = value.clone()
            continue
        source = inputs[packed]
        start = value.storage_offset() * value.element_size() - source.storage_offset()
        nbytes = value.numel() * value.element_size()
        view = static[packed][start : start + nbytes].view(value.dtype).view(value.shape)
        static[key] = view.copy_(value)
    return static


def host_state(
    state: dict[str, torch.Tensor], pinned: dict[str, torch.Tensor]
) -> dict[str, torch.Tensor]:
    """`state`'s tensors as CPU copies. On CUDA all of them are copied asynchronously into
    pinned buffers kept in `pinned` (one wait for them all, not one per tensor), then
    handed out as copies of those buffers, which the next call refills."""
    tensors = {k: v.detach() for k, v in state.items()}
    if not any(v.is_cuda for v in tensors.values()):
        return {k: v.to("cpu", copy=True) for k, v in tensors.items()}
    for key, value in tensors.items():
        if key not in pinned or pinned[key].shape != value.shape:
            pinned[key] = torch.empty(value.shape, dtype=value.dtype, pin_memory=True)
        pinned[key].copy_(value, non_blocking=True)
    torch.cuda.current_stream().synchronize()
    return {k: pinned[k].clone() for k in tensors}
