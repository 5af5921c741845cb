"""A trained run, loaded back the same way everywhere (`graft eval`, the benchmarks): its
config from ``RUN/config.yaml`` and a greedy behaviour from one of ``RUN/checkpoints``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from graft.config import TrainConfig, config_from_data, load_preset, preset_names
from service.core import as_arrays


def run_config(run_dir: Path) -> TrainConfig:
    """The config a run folder was trained with, read from the folder alone (whatever
    preset or YAML file it came from; its import path is recorded there).

    Raises:
        FileNotFoundError: ``run_dir`` has no config.yaml.
    """
    import yaml

    path = Path(run_dir) / "config.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir} is not a run folder: no config.yaml")
    data = yaml.safe_load(path.read_text()) or {}
    if "hardcoded_policy" not in data and data.get("preset") in preset_names():
        # A config.yaml that names no hard-coded policy takes its built-in preset's.
        data["hardcoded_policy"] = load_preset(data["preset"]).hardcoded_policy
    return config_from_data(data)


def load_behaviour(path: Path) -> tuple[Any, TrainConfig]:
    """The behaviour (its ``greedy`` is the trained policy, any algorithm) of a run folder
    at its latest checkpoint or of a checkpoint file in one, and the run's config.

    Raises:
        FileNotFoundError: no such run folder or checkpoint.
    """
    import torch

    from graft.registry import make_builder
    from learner.checkpoint import find_checkpoint, load_checkpoint

    checkpoint, run_dir = find_checkpoint(path)
    config = run_config(run_dir)
    builder = make_builder(config)
    learner = builder.make_learner()
    learner.load_state_dict(load_checkpoint(checkpoint)["algorithm"])
    behaviour = builder.make_behaviour(num_actors=1)
    behaviour.load(as_arrays(learner.policy_state()))
    torch.set_num_threads(1)  # one episode at a time; leave the other core to the env
    return behaviour, config


CORRECTED_LEAVES = {
    "minecraft.agent.travel_env:MinecraftTravel-v0": "travel",
    "minecraft.agent.drop_env:MinecraftDrops-v0": "drops",
}
"""The obtain-diamond tree's leaves a run can correct, by the environment it trained on."""


def load_corrections(runs: list[Path], travel_while: Sequence[str] = ()) -> Any:
    """The greedy policies of trained runs, each at the tree's leaf its task trains
    (``minecraft.agent.corrections.Corrections``): a travel run corrects "Step to
    cell" (only in the walks of the ``travel_while`` activities when some are given, for
    example "searching"), a drops run decides "Pick up drops".

    Raises:
        ValueError: a run of another task, two runs for one leaf, or an unknown activity.
        FileNotFoundError: no such run folder or checkpoint.
    """
    from minecraft.agent.corrections import Corrections
    from minecraft.agent.tree_profile import ACTIVITIES

    unknown = sorted(set(travel_while) - set(ACTIVITIES))
    if unknown:
        raise ValueError(f"unknown activity {unknown[0]!r}: one of {', '.join(ACTIVITIES)}")

    found: dict[str, Any] = {}
    for run in runs:
        behaviour, config = load_behaviour(Path(run))
        leaf = CORRECTED_LEAVES.get(config.env_id)
        if leaf is None:
            raise ValueError(
                f"{run} trained {config.env_id}, which corrects no leaf of the diamond tree; "
                f"runs of {sorted(CORRECTED_LEAVES)} do"
            )
        if leaf in found:
            raise ValueError(f"{run}: a second run for the {leaf} leaf")
        found[leaf] = _one_at_a_time(behaviour.greedy)
    if travel_while:
        if "travel" not in found:
            raise ValueError(f"travel activities {sorted(travel_while)} given, but no travel run")
        found["travel_activities"] = frozenset(travel_while)
    return Corrections(**found)


def _one_at_a_time(batched: Any) -> Any:
    import numpy as np

    def policy(obs: Any) -> Any:
        return np.asarray(batched(np.asarray(obs, np.float32)[None]))[0]

    return policy
