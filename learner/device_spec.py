"""The spellings of the ``learner`` section's device and compile fields, checked without
importing torch: a preset is validated before anything starts, and `graft`'s commands
answer bad input in one line without paying torch's import (the resolving is
`learner.device`'s, where the learner runs).
"""

from __future__ import annotations

import re
from typing import Literal

DEVICE_SPEC = re.compile(r"auto|cpu|cuda(:\d+)?")
"""The spellings of ``learner.device``."""
COMPILE_MODES = ("off", "auto", "compile", "cuda_graphs", "captured")
"""The values of ``learner.compile``."""
CompileMode = Literal["off", "compile", "cuda_graphs", "captured"]
"""A resolved compile mode: eager, ``torch.compile``, ``torch.compile`` with CUDA graphs
(the networks' forward passes), or the whole update captured as one CUDA graph."""


def check_device_spec(spec: str) -> None:
    """Refuses a ``learner.device`` that is none of auto, cpu, cuda, cuda:N (its spelling only;
    whether CUDA is there is `resolve_device`'s question, asked where the learner runs).

    Raises:
        ValueError: ``device=...`` naming the value and what is allowed.
    """
    if not isinstance(spec, str) or not DEVICE_SPEC.fullmatch(spec):
        raise ValueError(f"device={spec!r} must be auto, cpu, cuda or cuda:N (N a GPU index)")


def check_compile_mode(mode: str) -> None:
    """Refuses a ``learner.compile`` outside `COMPILE_MODES`."""
    if mode not in COMPILE_MODES:
        raise ValueError(f"compile={mode!r} must be one of {', '.join(COMPILE_MODES)}")
