"""The grid `graft tune` sweeps: knob names, the simulated costs that are not preset
fields, and every point's config, refused in one line before anything starts."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Optional

from graft.config import TrainConfig, load_preset
from graft.placement import local_cpus
from graft.validation import ConfigError

LEARNERS = ("real", "cost", "drain")


ALIASES = {
    "actors": "num_actors",
    "envs": "envs_per_actor",
    "publish_interval": "publish_every",
    "slack": "slack_env_steps",
    "replay_shards": "replay.shards",
}
"""Short names of config knobs (`batch_size` is the algorithm section's)."""


@dataclass(frozen=True)
class Costs:
    """What a point's simulated parts cost: the knobs that are not preset fields."""

    learner: str = "real"
    """real (the preset's algorithm), cost (a fixed time per update) or drain (none)."""
    learner_cost_ms: float = 0.0
    """Time per update of the `cost` learner."""
    learner_busy: bool = True
    """The `cost` learner busy-waits (True) or sleeps (False)."""
    step_cost_ms: float = 0.0
    """CPU busy-waited per simulated env step."""
    step_latency_ms: float = 0.0
    """Time slept per simulated env step."""
    actor_steps_per_s: float = 0.0
    """Most env steps per second of one actor (0: as fast as possible)."""
    tick_ms: float = 0.0
    """Real-time mode: each simulated world ticks every tick_ms; skipped ticks are counted."""
    actor_cpus: float = 0.25
    """CPUs Ray reserves for each actor."""
    samples_per_insert: Optional[float] = None
    """Sampled items per inserted item (None: the preset's updates_per_env_step x batch)."""

    def __post_init__(self) -> None:
        if self.learner not in LEARNERS:
            raise ValueError(f"learner={self.learner!r} is unknown; choose from {LEARNERS}")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not value >= 0:
                raise ValueError(f"{f.name}={value} must be >= 0")
        if self.actor_cpus <= 0:
            raise ValueError(f"actor_cpus={self.actor_cpus} must be > 0")
        if self.samples_per_insert is not None and self.samples_per_insert <= 0:
            raise ValueError(f"samples_per_insert={self.samples_per_insert} must be > 0")


COST_KNOBS = {f.name for f in dataclasses.fields(Costs)}


def knob_key(name: str, algorithm: str) -> str:
    """The preset key (or `Costs` field) a knob name stands for."""
    if name == "batch_size":
        return f"{'dqn' if algorithm == 'ddqn' else 'td3'}.batch_size"
    return ALIASES.get(name, name)


def parse_grid(pairs: Sequence[str]) -> dict[str, list[Any]]:
    """`--grid name=v1,v2,...` pairs as {name: [values]} (values parsed as YAML scalars).

    Raises:
        ConfigError: a pair without '=' or without values, or a knob named twice.
    """
    import yaml

    grid: dict[str, list[Any]] = {}
    for pair in pairs:
        name, sep, values = pair.partition("=")
        name = name.strip()
        if not sep or not name or not values.strip():
            raise ConfigError(f"--grid {pair!r}: expected name=v1,v2,..., e.g. actors=1,2,4")
        if name in grid:
            raise ConfigError(f"--grid {name} given twice; list all its values once")
        grid[name] = [yaml.safe_load(v) for v in values.split(",")]
    return grid


@dataclass(frozen=True)
class Point:
    """One grid point: its knob values, the run config and the costs they make."""

    knobs: dict[str, Any]
    config: TrainConfig
    costs: Costs


def plan(
    preset: str,
    grid: dict[str, list[Any]],
    *,
    overrides: dict[str, Any],
    costs: Costs,
    address: str,
) -> list[Point]:
    """Every grid point's config and costs, refused in one line before anything starts.

    Raises:
        ConfigError: an unknown knob, a value the config or the costs refuse, or more
            actor CPUs than a local Ray instance has.
    """
    base = load_preset(preset, **overrides)
    points = []
    for values in itertools.product(*grid.values()):
        knobs = dict(zip(grid, values, strict=True))
        config_overrides, cost_overrides = dict(overrides), {}
        for name, value in knobs.items():
            key = knob_key(name, base.algorithm)
            if key in COST_KNOBS:
                cost_overrides[key] = value
            else:
                config_overrides[key] = value
        try:
            point_costs = dataclasses.replace(costs, **cost_overrides)
        except (ValueError, TypeError) as e:
            raise ConfigError(f"--grid {knobs}: {e}") from None
        batch_key = knob_key("batch_size", base.algorithm)
        section, _, field = batch_key.partition(".")
        batch = config_overrides.get(batch_key, getattr(getattr(base, section), field))
        try:
            config = load_preset(preset, **_tuning_budget(config_overrides, int(batch)))
        except ConfigError as e:
            knobs_known = sorted({*ALIASES, "batch_size", *COST_KNOBS})
            raise ConfigError(f"{e}; tune's own knobs: {', '.join(knobs_known)}") from None
        if address == "local":
            need = config.num_actors * point_costs.actor_cpus
            have = local_cpus()
            if need > have:
                raise ConfigError(
                    f"{config.num_actors} actors x actor_cpus={point_costs.actor_cpus:g} need "
                    f"{need:g} CPUs; the local Ray instance has {have:g}"
                )
        points.append(Point(knobs, config, point_costs))
    return points


def _tuning_budget(overrides: dict[str, Any], batch_size: int) -> dict[str, Any]:
    """A budget no point reaches (a point ends after its measured time), and a table that
    starts sampling at two batches unless `learning_starts` is given."""
    return {"env_steps": 10**12, "learning_starts": 2 * batch_size, **overrides}
