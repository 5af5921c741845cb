"""Handing the memory the server has freed back to the OS: cyclic garbage and, where the
C allocator is glibc's, the free pages malloc keeps.

A refused streaming call can leave its last request in a reference cycle (gRPC's request
iterator is an async generator its receiver object holds), freed only by the cyclic garbage
collector, which counts objects, not bytes: megabyte requests pile up between its runs.
What is freed, glibc's malloc keeps in the arena of the thread that freed it and gives back
only from the top of a heap, so megabyte requests (refused or not) leave RSS tens of MiB up
for as long as the server runs. Once a second the server collects garbage, then hands every
free page of every arena back (`malloc_trim(0)`): RSS settles within a few MiB of what is
in use, at the cost of refaulting those pages when they are reused.
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
"""How often the server returns its freed memory to the OS."""


def _malloc_trim() -> Optional[Callable[[int], int]]:
    """glibc's `malloc_trim`, or None where the C library has none (musl, macOS)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def return_freed_memory(stop: threading.Event, every_s: float = TRIM_EVERY_S) -> None:
    """Until `stop` is set, each `every_s` seconds: collects cyclic garbage, then hands
    every free page of every malloc arena back to the OS (where the C library can)."""
    trim = _malloc_trim()
    if trim is None:
        log.info("no malloc_trim in this C library; freed memory stays with the allocator")
    while not stop.wait(every_s):
        gc.collect()
        if trim is not None:
            trim(0)
