"""Learner checkpoints: model, optimiser and counters, written atomically to the run folder."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional

import torch

KEEP = 3


def save_checkpoint(folder: Path, state: dict[str, Any], *, updates: int) -> Path:
    """Writes `ckpt-<updates>.pt` via a temporary file and rename: never half a file."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"ckpt-{updates:09d}.pt"
    tmp = path.with_suffix(".pt.tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    for old in sorted(folder.glob("ckpt-*.pt"))[:-KEEP]:
        old.unlink()
    return path


def latest_checkpoint(folder: Path) -> Optional[Path]:
    found = sorted(Path(folder).glob("ckpt-*.pt"))
    return found[-1] if found else None


def load_checkpoint(path: Path) -> dict[str, Any]:
    return torch.load(path, map_location="cpu", weights_only=False)
