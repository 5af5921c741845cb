"""Checks a run passes before anything is written or started: its task's import strings,
its run folder (new, or a resume that can continue it) and whether its actors can be placed
on a local Ray instance or the cluster."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Optional

import yaml

from actors.task import add_import_path
from graft.config import TrainConfig
from graft.placement import Node, Placement, check_placement, cluster_nodes, local_cpus
from graft.validation import ConfigError, check_env_id, resolve_import_string
from learner.checkpoint import latest_checkpoint

USES_HARDCODED_POLICY = ("backbone_td3", "pretrain_td3", "options")
"""The methods that build the preset's hard-coded policy (backbone_td3 unless it has a teacher)."""


def check_task(config: TrainConfig, *, policy: Optional[bool] = None) -> None:
    """Resolves the task's import strings in this process, the run's import path first:
    ``env_id``, ``obs_wrapper`` and, when `policy` (default: the method builds it),
    ``hardcoded_policy``.

    Raises:
        ConfigError: e.g. ``obs_wrapper='mypkg.wrap:Flat' does not resolve: no module named
            'mypkg' (...)``.
    """
    add_import_path(config.import_path)
    check_env_id(config.env_id)
    if config.obs_wrapper is not None:
        resolve_import_string("obs_wrapper", config.obs_wrapper)
    if policy is None:
        teacher = config.algorithm == "backbone_td3" and config.backbone.teacher
        policy = config.algorithm in USES_HARDCODED_POLICY and not teacher
    if policy and config.hardcoded_policy is not None:
        resolve_import_string("hardcoded_policy", config.hardcoded_policy)


def default_run_dir(config: TrainConfig) -> Path:
    return Path("runs") / f"{config.preset}-s{config.seed}-{time.strftime('%Y%m%d-%H%M%S')}"


def check_run_dir(
    config: TrainConfig, run_dir: Optional[Path], resume: bool
) -> tuple[Path, Optional[Path]]:
    """The run folder and, with `resume`, the checkpoint to continue from; writes nothing.

    Raises:
        ConfigError: a new run into a folder that holds files, or `resume` without a
            folder, without a checkpoint, or with another preset than the folder's run.
    """
    if not resume:
        run_dir = Path(run_dir) if run_dir else default_run_dir(config)
        if run_dir.exists() and (not run_dir.is_dir() or any(run_dir.iterdir())):
            if latest_checkpoint(run_dir / "checkpoints") is not None:
                raise ConfigError(
                    f"--run-dir {run_dir} already holds a run; give --resume to continue it, "
                    "or a new folder"
                )
            raise ConfigError(
                f"--run-dir {run_dir} already exists and holds no checkpoint to resume; "
                "remove it or give a new folder"
            )
        return run_dir, None
    if run_dir is None:
        raise ConfigError("--resume needs --run-dir, the folder of the run to continue")
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ConfigError(f"--resume: --run-dir {run_dir} does not exist")
    checkpoint = latest_checkpoint(run_dir / "checkpoints")
    if checkpoint is None:
        raise ConfigError(
            f"--resume: {run_dir} has no checkpoint to continue from "
            f"({run_dir / 'checkpoints'}/ckpt-*.pt)"
        )
    recorded = _recorded_preset(run_dir)
    if recorded is not None and recorded != config.preset:
        raise ConfigError(
            f"--resume: {run_dir} was trained with preset {recorded!r}, not "
            f"{config.preset!r}; resume it with its own preset"
        )
    return run_dir, checkpoint


def _recorded_preset(run_dir: Path) -> Optional[str]:
    """The preset recorded in a run folder's config.yaml (None if it has none)."""
    path = run_dir / "config.yaml"
    try:
        data = yaml.safe_load(path.read_text()) if path.is_file() else None
    except yaml.YAMLError:
        return None
    preset = data.get("preset") if isinstance(data, dict) else None
    return str(preset) if preset is not None else None


def ray_cpus(remote: Any) -> float:
    """CPUs a Ray actor class or task asks for (its decorator's num_cpus; Ray's default 1)."""
    return float(getattr(remote, "_default_options", {}).get("num_cpus", 1))


def run_roles(config: TrainConfig) -> list[tuple[str, Placement, int]]:
    """The Ray actors of one run, in placing order: its evaluator, then its env actors."""
    return [("evaluator", config.evaluator, 1), ("actors", config.actors, config.num_actors)]


def run_cpus(config: TrainConfig) -> float:
    """CPUs the Ray actors of one run ask for: its env actors and its evaluator."""
    return sum(p.num_cpus * n for _, p, n in run_roles(config))


def check_fits_locally(config: TrainConfig, address: str) -> None:
    """Refuses, before Ray starts, a run whose actors a new local Ray instance cannot
    place: the ones left pending would never insert, and the learner would wait forever.

    Raises:
        ConfigError: e.g. ``actors: 100 × (0.25 CPU) do not fit the local Ray instance
            (2 CPU on 1 eligible node(s)); only 7 fit. Use --actors 7, ...``.
    """
    if address != "local":
        return  # checked once connected (`check_cluster`)
    import torch

    node = Node("local", {"CPU": local_cpus(), "GPU": float(torch.cuda.device_count())})
    problem = check_placement(run_roles(config), [node], where="the local Ray instance")
    if problem is not None:
        raise ConfigError(problem)


def check_cluster(config: TrainConfig, address: str) -> None:
    """Refuses a run whose actors the connected cluster cannot place (its nodes' total
    resources and labels), in one line naming what is missing.

    Raises:
        ConfigError: e.g. ``actors.label_selector={'zone': 'b'} matches no node ...``.
    """
    where = "the local Ray instance" if address == "local" else f"the Ray cluster at {address}"
    problem = check_placement(run_roles(config), cluster_nodes(), where=where)
    if problem is not None:
        raise ConfigError(problem)
