"""Compiling numba kernels once per machine: processes started together (a fleet of
clients, world servers, the test suite) on a fresh install would each spend seconds of
CPU compiling the same kernels. Behind ``compile_lock`` the first writes numba's cache
and the others load it (`python bench/render_compile.py` measures both)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any


@contextlib.contextmanager
def compile_lock(kernels: str) -> Iterator[None]:
    """An exclusive lock, per user, over compiling ``kernels`` (none if the file cannot be
    opened: then each process compiles alone, as without the lock)."""
    path = Path(tempfile.gettempdir()) / f"graft-{kernels}-compile-{os.getuid()}.lock"
    try:
        file = path.open("a")
    except OSError:
        yield
        return
    with file:  # closing the file releases the lock
        fcntl.flock(file, fcntl.LOCK_EX)
        yield


def compile_once(kernels: str, dispatcher: Any, compile: Callable[[], None]) -> None:
    """Runs ``compile()`` (a call of numba ``dispatcher`` that compiles it, or loads it
    from numba's cache) under ``compile_lock(kernels)``, unless this process has it
    already."""
    if dispatcher.signatures:  # compiled in this process already
        return
    with compile_lock(kernels):
        compile()
