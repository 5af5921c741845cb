"""Learner checkpoints: model, optimiser and counters, written atomically to the run folder."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Optional

import torch

KEEP = 3


def save_checkpoint(folder: Path, state: dict[str, Any], *, updates: int, keep: int = KEEP) -> Path:
    """Writes `ckpt-<updates>.pt` via a temporary file and rename: never half a file; keeps
    the newest ``keep`` checkpoints (0: all of them)."""
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
    return torch.load(path, map_location="cpu", weights_only=False)
