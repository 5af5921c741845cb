"""The memory this process may use: its cgroup's limit where one is set, else the
machine's memory, less a margin for everything else it runs (the interpreter, gRPC,
torch). The replay server checks its tables against it; `graft train` its networks."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional

MARGIN_FRACTION = 0.1
"""Part of the limit kept for everything else (a tenth)..."""
MARGIN_MIN_BYTES = 256 * 2**20
"""...and at least this much: an interpreter with numpy and gRPC takes about 100 MiB."""
_UNLIMITED = 2**60
"""cgroup v1 writes 'no limit' as a number near 2**63."""


@dataclass(frozen=True)
class MemoryBudget:
    """Bytes a process may fill, and where the figure comes from (for the messages)."""

    bytes: int
    source: str
    """E.g. 'the cgroup memory limit 1.5 GiB less 256 MiB' or '--max-memory 2 GiB'."""

    def __str__(self) -> str:
        return f"{gib(self.bytes)} ({self.source})"


def gib(n: float) -> str:
    """Bytes in the unit a reader takes in at a glance: '394.2 GiB', '12.0 MiB'."""
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if abs(n) >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} B"


def memory_budget(max_bytes: Optional[int] = None) -> MemoryBudget:
    """The bytes this process may use: `max_bytes` when given (an operator's own bound),
    else the cgroup's memory limit where one is set, else the machine's memory; the
    latter two less a margin (a tenth, at least 256 MiB)."""
    if max_bytes is not None:
        return MemoryBudget(max_bytes, f"--max-memory {gib(max_bytes)}")
    limit = cgroup_limit()
    what = "the cgroup memory limit"
    if limit is None:
        limit, what = machine_memory(), "the machine's memory"
    margin = max(MARGIN_MIN_BYTES, int(limit * MARGIN_FRACTION))
    return MemoryBudget(max(limit - margin, 0), f"{what} {gib(limit)} less {gib(margin)}")


def machine_memory() -> int:
    """MemTotal from /proc/meminfo, in bytes."""
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemTotal:"):
            return int(line.split()[1]) * 1024
    raise OSError("/proc/meminfo has no MemTotal")


def cgroup_limit(
    proc_cgroup: Path = Path("/proc/self/cgroup"), root: Path = Path("/sys/fs/cgroup")
) -> Optional[int]:
    """The smallest memory limit on this process's cgroup and its ancestors (v2
    ``memory.max``, v1 ``memory.limit_in_bytes``), or None where none is set or readable."""
    try:
        lines = proc_cgroup.read_text().splitlines()
    except OSError:
        return None
    limits: list[int] = []
    for line in lines:
        _, controllers, path = line.split(":", 2)
        if controllers == "":  # cgroup v2
            base, name = root, "memory.max"
        elif "memory" in controllers.split(","):
            base, name = root / "memory", "memory.limit_in_bytes"
        else:
            continue
        folder = base / path.lstrip("/")
        for at in (folder, *folder.parents):
            value = _read_limit(at / name)
            if value is not None:
                limits.append(value)
            if at == base:
                break
    return min(limits) if limits else None


def _read_limit(path: Path) -> Optional[int]:
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    if not text.isdigit() or int(text) >= _UNLIMITED:
        return None  # 'max' (v2) or v1's near-2**63: no limit
    return int(text)
