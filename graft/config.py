"""Run configuration: a preset (YAML data) parsed once, at the entry point, into dataclasses."""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Iterable
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Optional

import yaml

from actors.task import EnvSpec, split_import_string
from graft import seeds
from graft.placement import ActorPlacement, LearnerPlacement, ReplaySettings
from graft.recipe import with_default_recipe
from graft.validation import (
    IMPORT_STRING_FIELDS,
    ConfigError,
    coerce,
    moved_import_string,
    unknown_fields,
    yaml_error,
)
from learner.backbone.config import BackboneConfig
from learner.dqn.config import DQNConfig
from learner.options.config import OptionsConfig
from learner.pretrain.config import PretrainConfig
from learner.selection import SelectionConfig
from learner.td3.config import TD3Config

ALGORITHMS = ("td3", "ddqn", "backbone_td3", "pretrain_td3", "options")
SECTIONS = {
    "td3": TD3Config,
    "dqn": DQNConfig,
    "backbone": BackboneConfig,
    "pretrain": PretrainConfig,
    "options": OptionsConfig,
    "selection": SelectionConfig,
    "actors": ActorPlacement,
    "evaluator": ActorPlacement,
    "learner": LearnerPlacement,
    "replay": ReplaySettings,
}
RECORDS = ("versions", "hardware")
"""What a run folder's config.yaml records beside the config (orchestration/provenance.py)."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run needs; one line per field, like a paper's hyper-parameter table."""

    preset: str
    """Name of the preset this run came from."""
    env_id: str = "Pendulum-v1"
    """The environment: a gymnasium id (``Pendulum-v1``, ``package.module:Env-v0``) or an
    import string ``package.module:Factory`` naming a ``gym.Env`` class or a function."""
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments of ``gym.make(env_id, ...)`` or of the factory (e.g.
    ``ticks_per_step`` of the Minecraft travel task); ``--set env_kwargs.NAME=VALUE``."""
    obs_wrapper: Optional[str] = None
    """Import string of a gymnasium wrapper (or function env -> env) applied to every
    environment: how Dict, tuple or image observations become a flat Box."""
    hardcoded_policy: Optional[str] = None
    """Import string ``package.module:factory`` of the hard-coded policy (a py_trees tree or
    a callable) that backbone_td3, pretrain_td3 and options improve."""
    import_path: list[str] = field(default_factory=list)
    """Folders put first on ``sys.path`` in this process and every actor before the import
    strings are resolved (default: the preset file's folder and the working directory)."""
    algorithm: str = "td3"
    """Learning algorithm: td3, ddqn, backbone_td3, pretrain_td3 or options."""
    recipe: Optional[str] = None
    """The default recipe (continuous or discrete) under this config, given because its
    preset names a hardcoded_policy and no algorithm (graft/recipe.py); else None."""
    env_steps: int = 20_000
    """Budget of environment steps (transitions) over all actors."""
    learning_starts: int = 1_000
    """Uniform-random steps before the policy acts; also the table's minimum size to sample."""
    updates_per_env_step: float = 1.0
    """Learner updates per environment step, held by the replay table's rate limiter."""
    slack_env_steps: int = 200
    """How many env steps actors may run ahead of (or behind) the update ratio before waiting."""
    num_actors: int = 2
    """Ray actors stepping environments."""
    clients: list[str] = field(default_factory=list)
    """Minecraft (Malmo) clients to play in, ``host:port`` each: `envs_per_actor` per
    actor, then one for the evaluator. Empty: every environment starts its own simulated
    world on its actor's node (graft/orchestration/clients.py)."""
    clients_file: Optional[str] = None
    """A file listing `clients`, one ``host:port`` a line (``#`` comments allowed)."""
    envs_per_actor: int = 4
    """Environments each actor steps side by side (one batched policy call per step)."""
    async_envs: bool = False
    """Each of an actor's environments steps at its own pace (real-time Minecraft clients,
    each world ticking on its own): the actor acts, batched, for whichever have their next
    observation. Off: in lock-step, every step waits for all of them (docs/tuning.md)."""
    actor_nice: Optional[int] = None
    """CPU niceness of each env actor's threads (acting, stepping its environments,
    writing to replay). None: Ray's worker niceness, 15, below every ordinary process;
    0 for real-time Minecraft clients on a machine that also runs Minecraft (lowering it
    needs CAP_SYS_NICE; an actor that may not reports the niceness it kept as
    ``actor/nice``)."""
    steps_per_insert: int = 8
    """Vectorised steps an actor collects before one insert (batch = steps × envs)."""
    replay_max_size: int = 1_000_000
    """Replay table capacity; the oldest transitions are evicted first."""
    prefetch: int = 4
    """Sampled batches the learner keeps in flight."""
    publish_every: int = 50
    """Learner updates between weight broadcasts."""
    eval_every: int = 1_000
    """Env steps between deterministic evaluations."""
    eval_episodes: int = 10
    """Episodes per evaluation."""
    checkpoint_every: int = 5_000
    """Learner updates between checkpoints (one more is written at the end)."""
    keep_checkpoints: int = 3
    """Newest checkpoints kept on disk; 0 keeps all (for learning curves over checkpoints)."""
    seed: int = 0
    """Seeds networks, actors' environments and exploration, and the replay sampler."""
    reproducible: bool = False
    """Lock-step mode: the learner drives the actors in a fixed order and samples exactly
    the held ratio, so a seed rewrites the same metrics.csv (slower); default asynchronous."""
    td3: TD3Config = field(default_factory=TD3Config)
    """TD3 hyper-parameters (td3, backbone_td3, pretrain_td3, the RL option)."""
    dqn: DQNConfig = field(default_factory=DQNConfig)
    """Double DQN hyper-parameters (ddqn, the policy over options)."""
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    """Backbone TD3: correction range, prefill noise, teacher (backbone_td3)."""
    pretrain: PretrainConfig = field(default_factory=PretrainConfig)
    """Demonstrations and pre-training losses (pretrain_td3)."""
    options: OptionsConfig = field(default_factory=OptionsConfig)
    """Option length, Retrace λ and the changes past the paper (options)."""
    selection: SelectionConfig = field(default_factory=SelectionConfig)
    """The final selection between the learned policy and the tree (the default recipe)."""
    actors: ActorPlacement = field(default_factory=ActorPlacement)
    """What each env actor reserves, where it may run, how often it is restarted."""
    evaluator: ActorPlacement = field(default_factory=ActorPlacement)
    """What the evaluator reserves, where it may run, how often it is restarted."""
    learner: LearnerPlacement = field(default_factory=LearnerPlacement)
    """What the learner reserves where it runs as a Ray task (``ray://`` addresses)."""
    replay: ReplaySettings = field(default_factory=ReplaySettings)
    """The replay servers: port, checkpoint interval, restarts and shards."""

    def __post_init__(self) -> None:
        for name in (
            "env_steps",
            "num_actors",
            "envs_per_actor",
            "steps_per_insert",
            "publish_every",
            "eval_every",
            "eval_episodes",
            "checkpoint_every",
        ):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}={getattr(self, name)} must be >= 1")
        if self.actor_nice is not None and not -20 <= self.actor_nice <= 19:
            raise ValueError(f"actor_nice={self.actor_nice} must be within -20..19 (Linux)")
        if self.recipe not in (None, "continuous", "discrete"):
            raise ValueError(f"recipe={self.recipe!r} must be continuous, discrete or null")
        if self.algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm={self.algorithm!r} is unknown; choose from {ALGORITHMS}")
        online = self.online_env_steps
        if online < 0:
            raise ValueError(
                f"env_steps={self.env_steps} is below pretrain.demo_steps="
                f"{self.pretrain.demo_steps}: the demonstrations count against the budget"
            )
        if online > 0 and not 0 < self.learning_starts < online:
            raise ValueError(
                f"learning_starts={self.learning_starts} must lie in (0, online env steps={online})"
            )
        if self.dqn.warmup == "hardcoded" and self.algorithm != "ddqn":
            raise ValueError(
                f"dqn.warmup=hardcoded is for algorithm ddqn (demonstrations of the hard-coded "
                f"policy), not {self.algorithm}: pretrain_td3 is its continuous-action "
                "counterpart"
            )
        tree_methods = (self.algorithm == "backbone_td3" and self.backbone.observe_backbone) or (
            self.algorithm == "ddqn" and self.dqn.warmup == "hardcoded"
        )
        if self.selection.episodes and not tree_methods:
            raise ValueError(
                f"selection.episodes={self.selection.episodes} falls back to the tree: it needs "
                "backbone_td3 with backbone.observe_backbone, or ddqn with dqn.warmup: hardcoded"
            )
        if self.backbone.clone_tree and self.td3.frozen_actor_updates == 0:
            raise ValueError(
                "backbone.clone_tree=true clones the tree while the actor is frozen: it needs "
                "td3.frozen_actor_updates > 0"
            )
        if self.updates_per_env_step <= 0:
            raise ValueError(f"updates_per_env_step={self.updates_per_env_step} must be > 0")
        self._check_seed_blocks()
        if self.keep_checkpoints < 0:
            raise ValueError(f"keep_checkpoints={self.keep_checkpoints} must be >= 0 (0: all)")
        if not isinstance(self.env_kwargs, dict):
            raise ValueError(f"env_kwargs={self.env_kwargs!r} must be a mapping of name: value")
        for name in ("obs_wrapper", "hardcoded_policy"):
            value = getattr(self, name)
            if value is not None:
                split_import_string(value, name)
        if not isinstance(self.clients, list) or not all(isinstance(c, str) for c in self.clients):
            raise ValueError(f"clients={self.clients!r} must be a list of host:port")
        if self.clients and self.clients_file:
            raise ValueError(f"clients and clients_file={self.clients_file!r}: give one of them")
        if self.async_envs and self.reproducible:
            raise ValueError(
                "async_envs=true with reproducible=true: the reproducible mode steps an "
                "actor's environments in lock-step; turn one of them off"
            )
        self._check_shards()
        if not isinstance(self.import_path, list) or not all(
            isinstance(p, str) for p in self.import_path
        ):
            raise ValueError(f"import_path={self.import_path!r} must be a list of folders")

    def _check_seed_blocks(self) -> None:
        """Refuses a seed, or more environments or evaluation episodes than one block of
        reset seeds holds (graft/seeds.py)."""
        if self.num_actors * self.envs_per_actor > seeds.BLOCK:
            raise ValueError(
                f"num_actors={self.num_actors} x envs_per_actor={self.envs_per_actor} must be "
                f"<= {seeds.BLOCK}: a run's environments reset from one block of "
                f"{seeds.BLOCK} seeds (graft/seeds.py)"
            )
        # With best_in_run the selection plays the episodes after the in-run ones.
        after = self.eval_episodes if self.selection.best_in_run else 0
        if max(self.eval_episodes, after + self.selection.episodes) > seeds.BLOCK:
            sum_of = " (their sum, with selection.best_in_run)" if after else ""
            raise ValueError(
                f"eval_episodes={self.eval_episodes} and selection.episodes="
                f"{self.selection.episodes} must be <= {seeds.BLOCK}{sum_of}: a run's "
                f"evaluation episodes reset from one block of {seeds.BLOCK} seeds "
                "(graft/seeds.py)"
            )
        if not 0 <= self.seed < 2**32:
            raise ValueError(f"seed={self.seed} must lie in [0, 2**32) (numpy's seed range)")

    def _check_shards(self) -> None:
        """Refuses a shard count the run cannot use: each shard needs a writer, a share
        of the table's minimum size and of the rate limiter's slack of at least one."""
        n = self.replay.shards
        if n == 1:
            return
        if self.reproducible:
            raise ValueError(
                f"replay.shards={n}: a reproducible run uses one replay server (replay.shards: 1)"
            )
        for name, value in (
            ("num_actors", self.num_actors),
            ("learning_starts", self.learning_starts),
            ("slack_env_steps", self.slack_env_steps),
        ):
            if value < n:
                raise ValueError(
                    f"replay.shards={n} needs {name} >= {n} (each shard gets its share), "
                    f"got {name}={value}"
                )

    @property
    def online_env_steps(self) -> int:
        """Env steps after the demonstrations (all of them unless pretrain_td3)."""
        demos = self.pretrain.demo_steps if self.algorithm == "pretrain_td3" else 0
        return self.env_steps - demos

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def env_spec(self) -> EnvSpec:
        """The task's environment as strings, for actors and the evaluator to build."""
        return EnvSpec(
            self.env_id, dict(self.env_kwargs), self.obs_wrapper, tuple(self.import_path)
        )

    def make_env(self) -> Any:
        """One environment of the task (``env_id`` with ``env_kwargs``, then ``obs_wrapper``).

        Raises:
            ValueError: an id or import string that does not resolve, or ``env_kwargs`` the
                environment refuses (names the keys).
        """
        try:
            return self.env_spec().make()
        except ValueError as error:
            raise ValueError(f"preset {self.preset}: {error}") from None


def _build(cls: type, data: dict[str, Any], section: str = "") -> Any:
    """``cls(**data)`` once every key is a field and every value has its field's type.

    Raises:
        ConfigError: one line naming the field (``td3.batch_size``), the value and what is
            allowed, for unknown keys, wrong types and values the dataclass refuses.
    """
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = set(data) - set(names)
    if unknown:
        raise ConfigError(unknown_fields(unknown, names, section=section))
    prefix = f"{section}." if section else ""
    values = {k: coerce(prefix + k, v, hints[k]) for k, v in data.items()}
    try:
        return cls(**values)
    except (ValueError, TypeError) as e:
        message = str(e).splitlines()[0] if str(e) else type(e).__name__
        if section and any(message.startswith(f"{name}=") for name in names):
            message = prefix + message  # "batch_size=0 ..." -> "td3.batch_size=0 ..."
        raise ConfigError(message) from None


PRESETS = resources.files("graft") / "presets"


def preset_names() -> list[str]:
    return sorted(
        p.name.removesuffix(".yaml") for p in PRESETS.iterdir() if p.name.endswith(".yaml")
    )


def preset_description(text: str) -> str:
    """A preset's one-line description: its first line, a comment."""
    first = text.split("\n", 1)[0].strip()
    return first.lstrip("#").strip() if first.startswith("#") else ""


def preset_descriptions() -> dict[str, str]:
    """Every shipped preset's name and one-line description (`graft presets`)."""
    return {
        name: preset_description((PRESETS / f"{name}.yaml").read_text()) for name in preset_names()
    }


def is_preset_path(name_or_path: str) -> bool:
    """A YAML path (ends .yaml/.yml or names a folder) rather than a shipped preset's name."""
    return Path(name_or_path).suffix in (".yaml", ".yml") or "/" in name_or_path


def _read_preset(name_or_path: str) -> tuple[dict[str, Any], str, Optional[Path]]:
    """A preset's fields, its name (a path's stem) and the folder of a preset file (None
    for a shipped preset); refuses unknown names, missing files and malformed YAML in one
    line."""
    if is_preset_path(name_or_path):
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(f"preset file {name_or_path} does not exist")
        text, name, folder = path.read_text(), path.stem, path.resolve().parent
    else:
        candidate = PRESETS / f"{name_or_path}.yaml"
        if not candidate.is_file():
            close = difflib.get_close_matches(name_or_path, preset_names(), n=3, cutoff=0.8)
            hint = f" (did you mean {' or '.join(close)}?)" if close else ""
            raise ConfigError(
                f"unknown preset {name_or_path!r}{hint}; presets: {', '.join(preset_names())} "
                "(`graft presets`), or a path to a YAML file"
            )
        text, name, folder = candidate.read_text(), name_or_path, None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise yaml_error(f"preset {name_or_path}", e) from None
    if data is None:
        return {}, name, folder
    if not isinstance(data, dict):
        raise ConfigError(
            f"preset {name_or_path}: expected a mapping of field: value, got a "
            f"{type(data).__name__}"
        )
    return data, name, folder


def _check_keys(keys: Iterable[str]) -> None:
    """Refuses a key naming no field ("td3.batchsize"), with the close matches."""
    top = {f.name for f in dataclasses.fields(TrainConfig)}
    for key in keys:
        section, _, name = key.partition(".")
        if section not in top:
            raise ConfigError(unknown_fields([section], top))
        if name and section in SECTIONS:
            fields = {f.name for f in dataclasses.fields(SECTIONS[section])}
            if name not in fields:
                raise ConfigError(unknown_fields([name], fields, section=section))


def _keys(data: dict[str, Any]) -> list[str]:
    """A preset's keys, a section's fields as "section.field"."""
    return [
        f"{key}.{name}" if key in SECTIONS and isinstance(value, dict) else key
        for key, value in data.items()
        for name in (value if key in SECTIONS and isinstance(value, dict) else [None])
    ]


def load_preset(name_or_path: str | Path, **overrides: Any) -> TrainConfig:
    """Reads a preset by name (graft/presets/NAME.yaml) or path; `overrides` win.

    An override key "section.field" (e.g. "pretrain.demo_noise") sets one field of a
    section; pass such keys with `**{"pretrain.demo_noise": 0.1}`, or a mapping for the
    section (`td3={"batch_size": 64}`) to set several. A preset given by path puts its
    folder (and the working directory) on the import path, where its import strings'
    modules are found; relative ``import_path`` entries count from the preset's folder.

    Raises:
        ConfigError: unknown preset or keys, malformed YAML, or values a run cannot use,
            in one line naming the field, the value and what is allowed.
    """
    data, name, folder = _read_preset(str(name_or_path))
    try:
        _check_keys(_keys(data))
    except ConfigError as e:
        raise ConfigError(f"preset {name_or_path}: {e}") from None
    data.setdefault("preset", name)
    listed = data.get("import_path") or []
    if not isinstance(listed, list) or not all(isinstance(p, str) for p in listed):
        raise ConfigError(f"import_path={listed!r} must be a list of folders")
    base = folder if folder is not None else Path.cwd()
    search = [str((base / p).resolve()) for p in listed]
    defaults = [str(folder)] if folder is not None else []
    data["import_path"] = _unique(search + defaults + [str(Path.cwd())])
    data = with_default_recipe(data, overrides, name=str(name_or_path))
    return config_from_data(data, **overrides)


def config_from_data(data: dict[str, Any], **overrides: Any) -> TrainConfig:
    """A config from parsed preset data (e.g. a run folder's config.yaml); `overrides` as
    in `load_preset`. The ``versions`` and ``hardware`` records in the data are ignored.

    Raises:
        ConfigError: unknown keys, or values a run cannot use, in one line.
    """
    data = {k: v for k, v in data.items() if k not in RECORDS}
    _check_keys(_keys(data))
    _check_keys(key for key, value in overrides.items() if value is not None)
    for key, value in overrides.items():
        if value is None:
            continue
        *path, last = key.split(".")  # "pretrain.demo_noise" -> data["pretrain"]["demo_noise"]
        node = data
        for depth, part in enumerate(path):
            child = node.get(part) or {}
            if not isinstance(child, dict):
                where = ".".join(path[: depth + 1])
                raise ConfigError(f"{where}={child!r} must be a mapping of name: value")
            node[part] = node = dict(child)
        if not path and last in SECTIONS and isinstance(value, dict):
            current = node.get(last) or {}
            if isinstance(current, dict):  # td3={"batch_size": 64} sets those fields only
                value = {**current, **value}
        node[last] = value
    for key in IMPORT_STRING_FIELDS:
        if key in data:
            data[key] = moved_import_string(key, data[key])
    for key, cls in SECTIONS.items():
        section = data.pop(key, None) or {}
        if isinstance(section, dict):
            section = _build(cls, section, key)
        elif not isinstance(section, cls):
            raise ConfigError(
                f"{key}={section!r} must be a mapping of {key}'s fields, e.g. {key}: "
                f"{{{dataclasses.fields(cls)[0].name}: ...}}"
            )
        data[key] = section
    return _build(TrainConfig, data)


def _unique(items: list[str]) -> list[str]:
    return list(dict.fromkeys(items))
