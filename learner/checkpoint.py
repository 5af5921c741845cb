"""Learner checkpoints: model, optimiser and counters, written atomically to the run folder.

Finding one needs no torch (the CLI checks a path before torch loads); saving and loading
import it."""

from __future__ import annotations

import errno
import io
import os
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

if TYPE_CHECKING:
    import torch

KEEP = 3
DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
"""The errors of a full disk (or a spent quota)."""


class DiskFull(OSError):
    """A write the disk had no room for; names the file and the space left."""

    def __init__(self, path: Path, free: int) -> None:
        super().__init__(errno.ENOSPC, f"disk full writing {path} ({free} bytes free)", str(path))
        self.path, self.free = path, free


def disk_full(error: BaseException, path: Path) -> Optional[DiskFull]:
    """`error` as a DiskFull naming `path` (the file a write failed on, when the error
    itself names none), or None when it is not a full disk."""
    if isinstance(error, DiskFull):
        return error
    if not (isinstance(error, OSError) and error.errno in DISK_FULL):
        return None
    where = Path(error.filename) if error.filename else path
    return DiskFull(where, free_bytes(where))


def free_bytes(path: Path) -> int:
    """Bytes free to this user on the filesystem holding `path` (or its nearest folder)."""
    for folder in (path, *path.parents):
        if folder.exists():
            return shutil.disk_usage(folder).free
    return 0


def remove_stale_temporaries(folder: Path) -> list[Path]:
    """Removes the ``*.pt.tmp`` files a run that stopped mid-write left (its disk filled,
    or it was killed); the checkpoints beside them are whole. Returns what it removed."""
    stale = sorted(Path(folder).glob("ckpt-*.pt.tmp")) if Path(folder).is_dir() else []
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def write_atomically(path: Path, text: str) -> None:
    """Writes `path` via a temporary file and rename: whole or not at all (a full disk
    leaves the old file, or none, and no temporary)."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)


def save_checkpoint(folder: Path, state: dict[str, Any], *, updates: int, keep: int = KEEP) -> Path:
    """Writes `ckpt-<updates>.pt` via a temporary file and rename: never half a file; keeps
    the newest ``keep`` checkpoints (0: all of them).

    Raises:
        DiskFull: the disk had no room; the temporary file is removed, the checkpoints
            before it are untouched.
    """
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"ckpt-{updates:09d}.pt"
    tmp = path.with_suffix(".pt.tmp")
    # Serialised in memory first: a full disk is then an OSError of our own write (torch's
    # writer says "unexpected pos" instead).
    buffer = io.BytesIO()
    torch.save(state, buffer)
    try:
        with open(tmp, "wb") as f:
            f.write(buffer.getbuffer())
    except OSError as error:
        tmp.unlink(missing_ok=True)
        full = disk_full(error, tmp)
        if full is None:
            raise
        raise full from None
    os.replace(tmp, path)
    if keep > 0:
        for old in sorted(folder.glob("ckpt-*.pt"))[:-keep]:
            old.unlink()
    return path


def latest_checkpoint(folder: Path) -> Optional[Path]:
    found = sorted(Path(folder).glob("ckpt-*.pt"))
    return found[-1] if found else None


def load_checkpoint(path: Path) -> dict[str, Any]:
    import torch

    return torch.load(path, map_location="cpu", weights_only=False)


def find_checkpoint(path: Path) -> tuple[Path, Path]:
    """(checkpoint file, run folder) for a run folder (its latest checkpoint) or a checkpoint
    file in one (``RUN/checkpoints/FILE``).

    Raises:
        FileNotFoundError: no checkpoint there.
    """
    path = Path(path)
    if path.is_dir():
        found = latest_checkpoint(path / "checkpoints")
        if found is None:
            raise FileNotFoundError(f"no checkpoint under {path}/checkpoints")
        return found, path
    if not path.is_file():
        raise FileNotFoundError(f"{path} is neither a run folder nor a checkpoint")
    return path, path.parent.parent


def load_generator_state(generator: torch.Generator, saved: torch.Tensor) -> None:
    """Restores a generator's state, or, when it was saved on another kind of device
    (CPU and CUDA generators keep different states), reseeds it from that state: the noise
    goes on from a fixed point, not the same stream."""
    saved = saved.cpu()
    try:
        generator.set_state(saved)
    except RuntimeError:
        seed = int.from_bytes(bytes(saved.tolist())[:8], "little") & (2**63 - 1)
        generator.manual_seed(seed)
