"""Learner checkpoints: model, optimiser and counters, written atomically to the run folder.

Finding one needs no torch (the CLI checks a path before torch loads); saving and loading
import it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

if TYPE_CHECKING:
    import torch

KEEP = 3


def save_checkpoint(folder: Path, state: dict[str, Any], *, updates: int, keep: int = KEEP) -> Path:
    """Writes `ckpt-<updates>.pt` via a temporary file and rename: never half a file; keeps
    the newest ``keep`` checkpoints (0: all of them)."""
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"ckpt-{updates:09d}.pt"
    tmp = path.with_suffix(".pt.tmp")
    torch.save(state, tmp)
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
