"""graft: train a hard-coded policy's improvement on your own task, load it, evaluate it.

    import graft
    run = graft.train("path/to/task.yaml", env_steps=20_000)
    policy = graft.load_policy(run.run_dir)
    graft.evaluate(policy, episodes=20).mean

This package is the top floor of the house, the only one that imports ``learner``,
``actors`` and ``minecraft``. Its layers, each importing only those below it (checked by
`lint-imports`): the command line (`cli`); the Python API (`api`), tuning (`tuning`) and
the paper's experiments (`experiments`); one training run (`orchestration`) and trained
runs (`trained`); a run's replay server processes (`replay_host`) and the algorithms'
builders (`registry`); config and presets (`config`); the recipe (`recipe`); placement
and validation of values (`placement`, `validation`).

The names below load on first use, so that ``graft --help`` does not import the run's
machinery.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from service import __version__

if TYPE_CHECKING:
    from graft.api import Evaluation, Policy, Run, evaluate, load_policy, train
    from graft.config import TrainConfig, load_preset

_LAZY = {
    "Evaluation": "graft.api",
    "Policy": "graft.api",
    "Run": "graft.api",
    "evaluate": "graft.api",
    "load_policy": "graft.api",
    "train": "graft.api",
    "TrainConfig": "graft.config",
    "load_preset": "graft.config",
}

__all__ = [
    "Evaluation",
    "Policy",
    "Run",
    "TrainConfig",
    "__version__",
    "evaluate",
    "load_policy",
    "load_preset",
    "train",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'graft' has no attribute {name!r}")
