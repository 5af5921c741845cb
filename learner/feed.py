"""A feed for a GPU learner that updates thousands of times a second: sampled batches
packed into a preallocated ring of pinned host buffers, several batches to one copy, the
next group's copy running on a side stream while the current updates run.

On the CPU (or with no batches ahead) `make_feed` keeps the plain `BatchFeed`, which hands
each batch over as it always did.
"""

from __future__ import annotations

import collections
from collections.abc import Callable
from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch

from learner.captured import PACKED
from learner.device import BatchFeed, learned_from
from service.core import Columns, TensorBatch

ALIGN = 64
"""Bytes each column's offset is a multiple of (any dtype's alignment)."""


@dataclass(frozen=True)
class Layout:
    """Where each learned-from column of a batch lies in its packed bytes."""

    columns: tuple[tuple[str, torch.dtype, tuple[int, ...], int], ...]
    """(name, dtype, shape, byte offset) of each column."""
    nbytes: int
    """Bytes of one packed batch (a multiple of `ALIGN`)."""

    @staticmethod
    def of(batch: Columns) -> Layout:
        columns, offset = [], 0
        for name, array in batch.items():
            if not learned_from(name):
                continue
            dtype = torch.from_numpy(np.empty(0, array.dtype)).dtype
            columns.append((name, dtype, tuple(array.shape), offset))
            offset += -(-array.nbytes // ALIGN) * ALIGN
        return Layout(tuple(columns), max(offset, ALIGN))

    def fits(self, batch: Columns) -> bool:
        return all(
            name in batch and tuple(batch[name].shape) == shape
            for name, _, shape, _ in self.columns
        )

    def pack(self, batch: Columns, into: np.ndarray) -> None:
        """`batch`'s columns copied into `into` (this layout's bytes)."""
        for name, _, _, offset in self.columns:
            array = np.ascontiguousarray(batch[name])
            into[offset : offset + array.nbytes] = array.reshape(-1).view(np.uint8)

    def views(self, packed: torch.Tensor, *, with_packed: bool) -> TensorBatch:
        """The columns as views of `packed` (one batch's bytes), and with `with_packed`
        `PACKED` itself (for a captured update; an eager one takes only columns)."""
        batch = {PACKED: packed} if with_packed else {}
        for name, dtype, shape, offset in self.columns:
            size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            batch[name] = packed[offset : offset + size].view(dtype).view(shape)
        return batch


class PinnedRing:
    """Sampled batches on a CUDA device, `group` of them per host-to-device copy.

    A ring of `slots` pinned host buffers and as many device buffers, each holding a group
    of packed batches (`Layout`): a group is drawn, packed into its pinned buffer and
    copied in one non-blocking copy on a side stream; its batches are handed out one by
    one as views of the device buffer (with `PACKED`, so that a captured update refills
    its static inputs in one copy), and the next group's copy starts as the current
    group's first batch is handed out. A buffer is refilled only after its copy is done
    (host side) and the updates that read it were queued before (device side).
    """

    def __init__(
        self,
        draw: Callable[[], Columns],
        *,
        device: torch.device,
        group: int,
        slots: int = 3,
        packed: bool = False,
    ) -> None:
        if group < 1 or slots < 2:
            raise ValueError(f"group={group} must be >= 1 and slots={slots} >= 2")
        self.draw, self.device, self.group, self.slots = draw, device, group, slots
        self.packed = packed
        self._copies = torch.cuda.Stream(device=device)
        self._layout: Optional[Layout] = None
        self._host: list[torch.Tensor] = []
        self._device: list[torch.Tensor] = []
        self._copied: list[Optional[torch.cuda.Event]] = [None] * slots
        self._read: list[Optional[torch.cuda.Event]] = [None] * slots
        self._next_slot = 0
        self._ready: collections.deque[tuple[int, list[Columns], torch.cuda.Event]]
        self._ready = collections.deque()
        self._current: Optional[tuple[int, list[Columns]]] = None
        self._handed = 0

    def next(self, *, left: int) -> tuple[Columns, TensorBatch]:
        """The next batch, as drawn and as tensors on the device; `left` (>= 1) is how many
        batches the phase still needs, so that nothing is drawn past its end."""
        if self._current is None or self._handed == len(self._current[1]):
            self._finish_current()
            if not self._ready:
                self._start(min(self.group, left))
            slot, batches, copied = self._ready.popleft()
            torch.cuda.current_stream(self.device).wait_event(copied)
            self._current, self._handed = (slot, batches), 0
            if left > len(batches):  # the next group's copy runs under these updates
                self._start(min(self.group, left - len(batches)))
        slot, batches = self._current
        assert self._layout is not None
        i = self._handed
        self._handed += 1
        nbytes = self._layout.nbytes
        packed = self._device[slot][i * nbytes : (i + 1) * nbytes]
        return batches[i], self._layout.views(packed, with_packed=self.packed)

    def _finish_current(self) -> None:
        """Marks the current group's device buffer read once the updates queued so far
        (the last ones that read it) have run."""
        if self._current is not None:
            event = torch.cuda.Event()
            event.record(torch.cuda.current_stream(self.device))
            self._read[self._current[0]] = event

    def _start(self, count: int) -> None:
        batches = [self.draw() for _ in range(count)]
        if self._layout is None or not all(self._layout.fits(b) for b in batches):
            self._allocate(Layout.of(batches[0]))
        assert self._layout is not None
        slot = self._next_slot
        self._next_slot = (slot + 1) % self.slots
        copied, read = self._copied[slot], self._read[slot]
        if copied is not None:
            copied.synchronize()  # its last copy left the pinned buffer
        host = self._host[slot].numpy()
        nbytes = self._layout.nbytes
        for i, batch in enumerate(batches):
            self._layout.pack(batch, host[i * nbytes : (i + 1) * nbytes])
        with torch.cuda.stream(self._copies):
            if read is not None:
                self._copies.wait_event(read)
            used = count * nbytes
            self._device[slot][:used].copy_(self._host[slot][:used], non_blocking=True)
            event = torch.cuda.Event()
            event.record(self._copies)
        self._copied[slot] = event
        self._ready.append((slot, batches, event))

    def _allocate(self, layout: Layout) -> None:
        """Buffers for `layout` (the first group's, or one whose columns changed)."""
        torch.cuda.current_stream(self.device).synchronize()
        self._layout = layout
        size = layout.nbytes * self.group
        self._host = [
            torch.empty(size, dtype=torch.uint8, pin_memory=True) for _ in range(self.slots)
        ]
        self._device = [
            torch.empty(size, dtype=torch.uint8, device=self.device) for _ in range(self.slots)
        ]
        self._copied = [None] * self.slots
        self._read = [None] * self.slots

    def in_flight(self) -> int:
        """Batches drawn ahead and not yet handed out."""
        current = 0 if self._current is None else len(self._current[1]) - self._handed
        return current + sum(len(batches) for _, batches, _ in self._ready)


def make_feed(
    draw: Callable[[], Columns],
    *,
    device: torch.device,
    depth: int,
    to_tensors: Callable[[Columns], TensorBatch],
    packed: bool = False,
) -> BatchFeed | PinnedRing:
    """The feed for `device`: on CUDA with batches ahead (`depth` > 0) a `PinnedRing` of
    groups of `depth` batches (`packed`: each batch also as its packed bytes, for a
    captured update); else the plain `BatchFeed`."""
    if device.type == "cuda" and depth > 0:
        return PinnedRing(draw, device=device, group=depth, packed=packed)
    return BatchFeed(draw, device=device, depth=depth, to_tensors=to_tensors)
