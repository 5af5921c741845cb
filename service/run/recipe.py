"""graft's default recipe: what a preset that names a ``hardcoded_policy`` and no
``algorithm`` trains with.

A user who brings a tree and asks "will it get better?" should not have to pick a method
and tune it. Such a preset gets one of two recipes (``service/run/recipes/*.yaml``, data
like the presets), chosen by the task's action space: ``continuous`` (a Box) or
``discrete``. The recipe lies under the preset: every field the preset (or an override)
sets wins, a section's fields one by one, so every knob stays reachable. What each recipe
does and why is in docs/own-task.md ("The default recipe").
"""

from __future__ import annotations

from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any, Optional

import numpy as np
import yaml
from gymnasium import spaces

from actors.task import EnvSpec
from service.run.validation import ConfigError

RECIPES = resources.files("service.run") / "recipes"
SECTIONS = ("td3", "dqn", "backbone", "pretrain", "options", "selection")
"""The preset sections a recipe may set (merged field by field with the preset's)."""
PREFILL_FRACTION = 10
"""A recipe's prefill (``learning_starts``) is at most 1/PREFILL_FRACTION of the budget."""
EXPLORATION_FRACTION = 0.16
"""The discrete recipe's ε decays over this share of the budget (rl-baselines3-zoo's
CartPole DQN: 8,000 of 50,000 steps)."""


def recipe_description(kind: str) -> str:
    """A recipe's one-line description: the first line of its YAML file, a comment."""
    first = (RECIPES / f"{kind}.yaml").read_text().split("\n", 1)[0].strip()
    return first.lstrip("#").strip()


SCALED = ("correction_limit", "prefill_noise")
"""The continuous recipe's backbone fields, written in units of the action box's largest
half-width (high - low) / 2 and scaled to the task's here: 2.0 is the whole box."""


def task_action_space(data: Mapping[str, Any]) -> spaces.Space:
    """The task's action space, from one environment.

    Raises:
        ConfigError: the environment does not build (e.g. a missing dependency), in one line.
    """
    spec = EnvSpec(
        str(data.get("env_id", "Pendulum-v1")),
        dict(data.get("env_kwargs") or {}),
        data.get("obs_wrapper"),
        tuple(data.get("import_path") or ()),
    )
    try:
        env = spec.make()
    except ValueError as error:
        raise ConfigError(str(error).splitlines()[0]) from None
    action_space = env.action_space
    env.close()
    return action_space


def with_default_recipe(
    data: dict[str, Any], overrides: Mapping[str, Any], *, name: str
) -> dict[str, Any]:
    """The preset's data on top of the default recipe when it names a hard-coded policy
    and neither it nor an override names an algorithm; else the data as it is.

    Args:
        data: The preset's fields (import path resolved).
        overrides: The caller's overrides (``algorithm=...`` among them opts out).
        name: The preset, for messages.

    Raises:
        ConfigError: the task's environment does not build, in one line.
    """
    chosen = {key for key, value in overrides.items() if value is not None}
    if "algorithm" in data or "algorithm" in chosen or not data.get("hardcoded_policy"):
        return data
    try:
        action_space = task_action_space(data)
    except ConfigError as error:
        raise ConfigError(f"preset {name}: {error}") from None
    kind = "discrete" if isinstance(action_space, spaces.Discrete) else "continuous"
    recipe = yaml.safe_load((RECIPES / f"{kind}.yaml").read_text())
    if isinstance(action_space, spaces.Box):
        half = float(np.max((action_space.high - action_space.low) / 2))
        backbone = recipe.get("backbone", {})
        recipe["backbone"] = {k: v * half if k in SCALED else v for k, v in backbone.items()}
    merged: dict[str, Any] = {**recipe, **data, "recipe": kind}
    for section in SECTIONS:
        mine, theirs = recipe.get(section), data.get(section)
        if isinstance(mine, dict) and isinstance(theirs, dict):
            merged[section] = {**mine, **theirs}
    budget = overrides.get("env_steps") or data.get("env_steps")
    if "learning_starts" not in data and "learning_starts" not in chosen and budget:
        # A short budget keeps its room to learn: the prefill takes at most a tenth of it.
        merged["learning_starts"] = max(1, min(recipe["learning_starts"], int(budget) // 10))
    preset_dqn = data.get("dqn") if isinstance(data.get("dqn"), dict) else {}
    if kind == "discrete" and budget and "epsilon_decay_env_steps" not in preset_dqn:
        decay = max(1, round(EXPLORATION_FRACTION * int(budget)))
        merged["dqn"] = {**merged["dqn"], "epsilon_decay_env_steps": decay}
    return merged


def recipe_line(preset: str, kind: Optional[str]) -> Optional[str]:
    """What `graft train` says about the recipe a run got (None when it got none)."""
    if kind is None:
        return None
    where = Path("docs") / "own-task.md"
    return (
        f"preset {preset} names a hardcoded_policy and no algorithm: graft's default recipe "
        f"for {kind} actions, {recipe_description(kind)} ({where}, 'The default recipe'; "
        "set algorithm: to choose another)"
    )
