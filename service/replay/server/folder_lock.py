"""One replay server per checkpoint folder: an exclusive lock held for the server's life."""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO

LOCK_NAME = "LOCK"


class FolderInUse(ValueError):
    """Another live process holds the checkpoint folder."""


def lock_folder(folder: Path) -> IO[str]:
    """Takes `folder/LOCK` (flock, released by the kernel when this process ends, even by
    SIGKILL) and writes our pid into it; keep the returned file open while serving.

    Raises:
        FolderInUse: naming the folder and the pid of the server that holds it.
    """
    handle = open(folder / LOCK_NAME, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "unknown"
        handle.close()
        raise FolderInUse(
            f"checkpoint folder {folder} is in use by another replay server (pid {holder}); "
            "stop that server or choose another --checkpoint-dir"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
    return handle
