"""Handing the memory refused and aborted calls freed back to the OS: their cyclic garbage
and, where the C allocator is glibc's, the free pages malloc keeps.

A refused streaming call can leave its last request in a reference cycle (gRPC's request
iterator is an async generator its receiver object holds), freed only by the cyclic garbage
collector, which counts objects, not bytes: megabyte requests pile up between its runs.
What is freed, glibc's malloc keeps in the arena of the thread that freed it and gives back
only from the top of a heap, so megabyte requests leave RSS tens of MiB up for as long as
the server runs. After calls were refused or aborted, once a second until `QUIET_PASSES`
seconds have passed without one, the server collects garbage, then hands every free page
of every arena back (`malloc_trim(0)`): RSS settles within a few MiB of what is in use.

No pass is made while no call is refused, for both halves cost: a full collection holds
the GIL for as long as it walks every tracked object (20 to 30 ms for the 40,000 a server
holds at start, every call waiting meanwhile), and a trim makes the next inserts fault
their pages back in. The objects alive when the passes start (modules, classes, tables)
are frozen out of the collector's sight (`gc.freeze`), so a pass walks only what was
made since (under a millisecond).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import threading
from collections.abc import Callable
from typing import Optional

log = logging.getLogger(__name__)

TRIM_EVERY_S = 1.0
"""How often the server returns its freed memory to the OS, while calls are refused."""
QUIET_PASSES = 5
"""Passes made after the last refused or aborted call: what one pass collects, gRPC frees
a moment later (a call's buffers, a closed connection's), for the next pass to hand back;
on a loaded machine that moment stretches to seconds."""


def _malloc_trim() -> Optional[Callable[[int], int]]:
    """glibc's `malloc_trim`, or None where the C library has none (musl, macOS)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


class FreedMemory:
    """Counts the calls that may leave garbage behind; `run` hands their memory back."""

    def __init__(self, every_s: float = TRIM_EVERY_S, quiet_passes: int = QUIET_PASSES) -> None:
        self.every_s = every_s
        self.quiet_passes = quiet_passes
        self.passes = 0
        """Passes made so far."""
        self._ended = 0  # refused or aborted calls; only the event loop's thread adds

    def call_ended_badly(self) -> None:
        """A call was refused or aborted: its request may sit in garbage until a pass."""
        self._ended += 1

    def run(self, stop: threading.Event) -> None:
        """Until `stop` is set: each `every_s` seconds while refused or aborted calls have
        ended in the last `quiet_passes` periods, collects cyclic garbage, then hands every
        free page of every malloc arena back to the OS (where the C library can)."""
        trim = _malloc_trim()
        if trim is None:
            log.info("no malloc_trim in this C library; freed memory stays with the allocator")
        gc.freeze()
        seen, quiet = self._ended, self.quiet_passes
        while not stop.wait(self.every_s):
            ended = self._ended
            if ended != seen:
                seen, quiet = ended, 0
            elif quiet >= self.quiet_passes:
                continue
            else:
                quiet += 1
            gc.collect()
            if trim is not None:
                trim(0)
            self.passes += 1
