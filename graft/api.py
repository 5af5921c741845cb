"""graft as a library: train a preset, load a policy, evaluate it (``import graft``).

    import graft
    run = graft.train("task.yaml", env_steps=20_000, td3={"batch_size": 128})
    policy = graft.load_policy(run.run_dir)        # the greedy policy, with its task
    print(graft.evaluate(policy, episodes=20).mean)

The ``graft`` command line calls these same functions.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from actors.task import EnvSpec
from graft.config import TrainConfig, config_from_data, load_preset
from service.core import Evaluation as LearnerEvaluation

PresetSource = Union[TrainConfig, str, Path]
"""A parsed config, a preset name or the path of a preset YAML file."""


@dataclass(frozen=True)
class Run:
    """A finished training run: its folder and what it reported."""

    run_dir: Path
    """The run folder (config.yaml, checkpoints/, metrics.csv, summary.json, ...)."""
    config: TrainConfig
    """The resolved config it trained with (also in ``run_dir/config.yaml``)."""
    summary: dict[str, Any]
    """``summary.json``: env steps, updates, final evaluation return, throughput."""
    evaluations: list[LearnerEvaluation]
    """Every evaluation the learner ran (mean and std of the returns, with its step)."""
    interrupted: bool = False
    """Ctrl-C stopped the run; its last checkpoint holds the state at
    ``summary['env_steps']``."""
    stopped: Optional[str] = None
    """Why the run stopped before its budget (the disk filled), in one line; None when it
    finished or was interrupted."""

    def policy(self) -> Policy:
        """The run's greedy policy (its latest checkpoint)."""
        return load_policy(self.run_dir)


class Policy:
    """A deterministic policy together with the task it acts in.

    Call it on one observation (returns one action) or on a batch ``[B, *obs_shape]``
    (returns ``[B, *action_shape]``). Observations are the environment's after the task's
    ``obs_wrapper``: `make_env` builds that environment.
    """

    def __init__(
        self,
        act: Callable[[np.ndarray], np.ndarray],
        *,
        env: EnvSpec,
        observation_shape: tuple[int, ...],
        name: str,
    ) -> None:
        """Wraps ``act``, a batched policy, for ``env``; ``name`` is how reports call it."""
        self.act, self.env, self.name = act, env, name
        self.observation_shape = observation_shape

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        if obs.shape == self.observation_shape:
            return np.asarray(self.act(obs[None]))[0]
        return np.asarray(self.act(obs))

    def make_env(self) -> Any:
        """One environment of the policy's task, as graft builds it for actors."""
        return self.env.make()


@dataclass(frozen=True)
class Evaluation:
    """Undiscounted returns of deterministic episodes (episode i reset with seed + i)."""

    returns: np.ndarray
    """float64 [episodes], in episode order."""
    env_id: str
    seed: int
    metrics: dict[str, np.ndarray] = field(default_factory=dict)
    """The environment's own metrics (``info["episode_metrics"]`` at each episode's end),
    by name, float64 [episodes] (NaN where an episode did not report one)."""

    @property
    def mean(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std(self) -> float:
        return float(np.std(self.returns))


def _config(source: PresetSource, overrides: dict[str, Any]) -> TrainConfig:
    if isinstance(source, TrainConfig):
        return config_from_data(source.to_dict(), **overrides) if overrides else source
    return load_preset(source, **overrides)


def train(
    config_or_preset: Optional[PresetSource] = None,
    *,
    run_dir: Optional[Union[str, Path]] = None,
    resume: bool = False,
    address: str = "local",
    progress: bool = False,
    **overrides: Any,
) -> Run:
    """Trains a preset end to end (Ray actors, replay server, learner) and returns the run.

    Ctrl-C stops the run cleanly (a final checkpoint, summary.json); the returned run says
    ``interrupted``.

    Args:
        config_or_preset: A `TrainConfig`, a preset name or a preset YAML path. None with
            ``resume``: the config recorded in ``run_dir`` (whatever preset it came from).
        run_dir: The run folder; default ``runs/<preset>-s<seed>-<time>``.
        resume: Continue from ``run_dir``'s latest checkpoint.
        address: ``local`` starts a Ray instance (unless one is running in this process);
            ``auto`` or ``ray://host:port`` joins a cluster.
        progress: Show a progress bar.
        **overrides: Preset fields: ``env_steps=5000``, ``seed=1``, a section as a mapping
            (``td3={"batch_size": 64}``) or one field of it (``**{"td3.batch_size": 64}``).

    Raises:
        ValueError: A preset, override or task the method cannot use (one line).
    """
    from graft.orchestration.launcher import train as launch
    from graft.trained import run_config

    if config_or_preset is None:
        if not (resume and run_dir is not None):
            raise ValueError("train needs a config or preset, or resume=True with a run_dir")
        config = config_from_data(run_config(Path(run_dir)).to_dict(), **overrides)
    else:
        config = _config(config_or_preset, overrides)
    result = launch(
        config,
        address=address,
        run_dir=Path(run_dir) if run_dir is not None else None,
        resume=resume,
        progress=progress,
    )
    return Run(
        result.run_dir,
        config,
        result.summary,
        result.evaluations,
        interrupted=result.interrupted,
        stopped=result.stopped,
    )


def load_policy(source: Union[str, Path, Run], *, preset: Optional[PresetSource] = None) -> Policy:
    """A policy with its task: a trained run's greedy policy, or the task's own.

    Args:
        source: A run folder (its latest checkpoint), a checkpoint file in one, a `Run`;
            or ``"hardcoded"`` (the preset's hard-coded policy alone) or ``"random"``
            (uniform random actions), on the task of ``preset``.
        preset: The task of ``"hardcoded"`` and ``"random"``: a config, preset name or
            YAML path (default ``pendulum-td3``). Ignored for a run.

    Raises:
        FileNotFoundError: No run folder or checkpoint at ``source``.
        ValueError: The preset names no hard-coded policy, or a task that does not build.
    """
    if isinstance(source, Run):
        source = source.run_dir
    if str(source) in ("hardcoded", "random"):
        config = _config(preset if preset is not None else "pendulum-td3", {})
        return _task_policy(str(source), config)
    from graft.trained import load_behaviour

    behaviour, config = load_behaviour(Path(source))
    env = config.make_env()
    shape = tuple(env.observation_space.shape or ())
    env.close()
    return Policy(
        behaviour.greedy, env=config.env_spec(), observation_shape=shape, name=str(source)
    )


def _task_policy(kind: str, config: TrainConfig) -> Policy:
    """The task's hard-coded policy or a uniform random one, as a `Policy`."""
    from actors.evaluator import random_policy_for
    from actors.hardcoded import check_acts, make_hardcoded_policy

    env = config.make_env()
    obs_space, action_space = env.observation_space, env.action_space
    env.close()
    spec = config.env_spec()
    act: Callable[[np.ndarray], np.ndarray]
    if kind == "random":
        act = random_policy_for(spec, seed=config.seed)
    elif config.hardcoded_policy is None:
        raise ValueError(
            f"preset {config.preset} names no hardcoded_policy: set hardcoded_policy: "
            "package.module:factory"
        )
    else:
        act = make_hardcoded_policy(
            config.hardcoded_policy, obs_space, action_space, import_path=config.import_path
        )
        check_acts(act, obs_space, name=config.hardcoded_policy)
    shape = tuple(obs_space.shape or ())
    return Policy(act, env=spec, observation_shape=shape, name=kind)


def evaluate(
    policy_or_run: Union[Policy, Run, str, Path, Callable[[np.ndarray], np.ndarray]],
    *,
    env: Optional[Union[EnvSpec, str]] = None,
    episodes: int = 10,
    seed: int = 0,
) -> Evaluation:
    """Runs deterministic episodes and returns their returns.

    Args:
        policy_or_run: A `Policy` (`load_policy`), a `Run` or a run folder, or any batched
            callable ``[B, *obs_shape] -> [B, *action_shape]`` (then ``env`` is needed).
        env: The environment (a gymnasium id, an import string or an `EnvSpec`); default
            the policy's own task.
        episodes: Episodes to run, all side by side.
        seed: Episode i is reset with ``seed + i``.

    Raises:
        ValueError: ``episodes`` < 1, or a bare callable without ``env``.
    """
    from actors.evaluator import play_episodes

    policy: Any = policy_or_run
    if isinstance(policy, Run | str | Path):
        policy = load_policy(policy)
    if env is None:
        if not isinstance(policy, Policy):
            raise ValueError("evaluate: pass env= for a policy that is not from load_policy")
        env = policy.env
    act = policy.act if isinstance(policy, Policy) else policy
    spec = EnvSpec(env) if isinstance(env, str) else env
    played = play_episodes(act, env=spec, episodes=episodes, seed=seed)
    return Evaluation(played.returns, spec.env_id, seed, played.metrics)
