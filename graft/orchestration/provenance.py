"""What a run folder records about where it came from: the resolved config and versions.

``RUN/config.yaml`` is the full resolved config (import strings, import path and every
hyper-parameter), loadable without the preset it came from, followed by ``versions``:
graft's, Python's and the main libraries', and those of the packages the import strings
name (the user's task), so a run can be traced to the code that produced it, and
``hardware``: the device the learner computed on and its name.
"""

from __future__ import annotations

import functools
import importlib.metadata as metadata
import platform
import sys
from typing import Any, Optional

import yaml

from graft.config import TrainConfig

GRAFT_DISTRIBUTION = "graft-rl"
LIBRARIES = ("torch", "ray", "gymnasium", "numpy", "py_trees")
GRAFT_PACKAGES = ("actors", "learner", "service", "graft")


def _version(distribution: str) -> str:
    try:
        return metadata.version(distribution)
    except metadata.PackageNotFoundError:
        return "not installed"


@functools.cache
def _distributions() -> dict[str, list[str]]:
    """Top-level module -> installed distributions providing it (read once: a scan of
    every installed package's metadata)."""
    return dict(metadata.packages_distributions())


def _module_version(module_name: str) -> str:
    """The version of the distribution that provides a top-level module, else the
    module's ``__version__``, else where it was loaded from."""
    distributions = _distributions().get(module_name, [])
    if distributions:
        return ", ".join(f"{d} {_version(d)}" for d in sorted(set(distributions)))
    module = sys.modules.get(module_name)
    version = getattr(module, "__version__", None)
    if version is not None:
        return str(version)
    return f"not installed ({getattr(module, '__file__', None) or 'not imported'})"


def task_modules(config: TrainConfig) -> list[str]:
    """Top-level modules the config's import strings name, graft's own and gymnasium's
    registered ids left out."""
    names = []
    for spec in (config.env_id, config.obs_wrapper, config.hardcoded_policy):
        module, sep, _ = (spec or "").partition(":")
        top = module.split(".")[0]
        if sep and top and top not in GRAFT_PACKAGES and top != "gymnasium":
            names.append(top)
    return list(dict.fromkeys(names))


def versions(config: TrainConfig) -> dict[str, Any]:
    """graft's version, Python's and the libraries', and the task modules' packages'."""
    record: dict[str, Any] = {
        GRAFT_DISTRIBUTION: _version(GRAFT_DISTRIBUTION),
        "python": platform.python_version(),
    }
    record.update({name: _version(name) for name in LIBRARIES})
    task = {name: _module_version(name) for name in task_modules(config)}
    if task:
        record["task"] = task
    return record


def config_record(config: TrainConfig, *, hardware: Optional[dict[str, str]] = None) -> str:
    """The text of ``RUN/config.yaml``: the config, then its ``versions`` and the
    ``hardware`` it ran on (e.g. the learner's device and its name)."""
    record = {**config.to_dict(), "versions": versions(config)}
    if hardware:
        record["hardware"] = dict(hardware)
    return yaml.safe_dump(record, sort_keys=False, allow_unicode=True)
