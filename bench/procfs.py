"""A process's figures as Linux's /proc gives them: status fields, resident memory, CPU time.

The chaos and Minecraft benchmarks read their server processes through these.
"""

from __future__ import annotations

import os


def proc_status(pid: int, key: str) -> int:
    """The number of a ``/proc/<pid>/status`` field (``VmRSS``, ``VmHWM`` in KiB, ``Threads``)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"no {key}")


def rss_mib(pid: int) -> float:
    """Resident memory in MiB."""
    return proc_status(pid, "VmRSS") / 1024


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds the process has used so far."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
