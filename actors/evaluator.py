"""Deterministic evaluation: the mean-return figures of the paper and the Ray actor that
scores published weights with them.

Episodes are stepped side by side in plain gymnasium environments with our own loop
(no vector-env autoreset), so episode ``i`` is always seeded with ``seed + i`` and its
return does not depend on how many environments run at once.

An environment reports metrics of its own in the ``info`` of an episode's last step,
``info["episode_metrics"] = {"success": 1.0, ...}``: each evaluation logs their means over
its episodes as ``eval/<name>`` beside the return.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Optional

import gymnasium as gym
import numpy as np
import ray
from ray import ObjectRef
from ray.exceptions import RayActorError, RayTaskError

from actors.policies import UniformRandomPolicy
from actors.task import EnvSpec
from service.core import Behaviour, EvalTag, Evaluation, WeightArrays, Weights, as_arrays

Policy = Callable[[np.ndarray], np.ndarray]
"""A batched policy: observations [B, *obs_shape] -> actions [B, *action_shape]."""

ADOPT_S = 2.0
"""How long `RemoteEvaluator` waits for a kept evaluator to take its run before it starts
a new one (a kept evaluator may still be scoring its last run's final weights)."""
EPISODE_METRICS = "episode_metrics"
"""``info`` key of the last step of an episode: the environment's own metrics, {name: float}."""


@dataclass(frozen=True)
class Episodes:
    """What a batch of episodes gave: their returns and the environment's own metrics."""

    returns: np.ndarray
    """Undiscounted returns, float64 [episodes], in episode order."""
    metrics: dict[str, np.ndarray] = field(default_factory=dict)
    """``info["episode_metrics"]`` of each episode's last step, by name: float64
    [episodes] (NaN for an episode that did not report the metric)."""

    def metric_means(self) -> dict[str, float]:
        """Each metric's mean over the episodes that reported it."""
        return {name: float(np.nanmean(values)) for name, values in self.metrics.items()}


def run_episodes(
    policy: Policy,
    *,
    env: EnvSpec | str = "Pendulum-v1",
    episodes: int = 100,
    seed: int = 0,
    num_envs: int | None = None,
) -> np.ndarray:
    """Runs full episodes and returns their undiscounted returns (`play_episodes`' returns)."""
    return play_episodes(policy, env=env, episodes=episodes, seed=seed, num_envs=num_envs).returns


def play_episodes(
    policy: Policy,
    *,
    env: EnvSpec | str = "Pendulum-v1",
    episodes: int = 100,
    seed: int = 0,
    num_envs: int | None = None,
) -> Episodes:
    """Runs full episodes; returns their undiscounted returns and the env's own metrics.

    Each step calls ``policy`` once on the observations of all running environments.
    An episode ends on termination or truncation (time limit); a finished environment
    starts the next pending episode.

    Args:
        policy: Batched policy; called with [B, *obs_shape], must return [B, ...].
        env: The task's environment (a run config's ``env_spec()``), or a gymnasium id.
        episodes: Number of episodes to run.
        seed: Episode ``i`` is reset with ``seed + i``.
        num_envs: Environments stepped side by side; all ``episodes`` at once when None.

    Returns:
        The returns, float64 [episodes] in episode order, and the metrics the environment
        put in ``info["episode_metrics"]`` at the end of each episode.

    Raises:
        ValueError: If ``episodes`` or ``num_envs`` is not positive, the policy returns
            the wrong batch size, or an episode's metrics are not a mapping of numbers.
    """
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")
    num_envs = episodes if num_envs is None else num_envs
    if num_envs < 1:
        raise ValueError(f"num_envs={num_envs} must be >= 1")
    num_envs = min(num_envs, episodes)

    spec = EnvSpec(env) if isinstance(env, str) else env
    envs = [spec.make() for _ in range(num_envs)]
    returns = np.zeros(episodes, dtype=np.float64)
    metrics: dict[str, np.ndarray] = {}
    episode_of = list(range(num_envs))  # episode each env is running; -1 when idle
    obs = [envs[k].reset(seed=seed + k)[0] for k in range(num_envs)]
    next_episode = num_envs
    try:
        while True:
            running = [k for k in range(num_envs) if episode_of[k] >= 0]
            if not running:
                break
            actions = np.asarray(policy(np.stack([obs[k] for k in running])))
            if actions.shape[0] != len(running):
                raise ValueError(
                    f"policy returned {actions.shape[0]} actions for {len(running)} observations"
                )
            for action, k in zip(actions, running, strict=True):
                obs[k], reward, terminated, truncated, info = envs[k].step(action)
                returns[episode_of[k]] += float(reward)
                if terminated or truncated:
                    _record(metrics, info.get(EPISODE_METRICS), episode_of[k], episodes)
                    if next_episode < episodes:
                        episode_of[k] = next_episode
                        obs[k] = envs[k].reset(seed=seed + next_episode)[0]
                        next_episode += 1
                    else:
                        episode_of[k] = -1
    finally:
        for made in envs:
            made.close()
    return Episodes(returns, metrics)


def _record(metrics: dict[str, np.ndarray], reported: Any, episode: int, episodes: int) -> None:
    """Files one episode's ``info["episode_metrics"]`` under each metric's name."""
    if reported is None:
        return
    if not isinstance(reported, dict):
        raise ValueError(
            f"info[{EPISODE_METRICS!r}] is {reported!r}; it must map metric names to numbers"
        )
    for name, value in reported.items():
        metrics.setdefault(str(name), np.full(episodes, np.nan))[episode] = float(value)


def random_policy_for(env: EnvSpec | str, *, seed: int = 0) -> Policy:
    """Returns a uniform random batched policy over an environment's action space.

    Args:
        env: The environment (or its gymnasium id), with a bounded ``Box`` or a
            ``Discrete`` action space.
        seed: Seed of the policy's own random generator.

    Returns:
        A policy mapping [B, *obs_shape] to actions [B, *action_shape] (float32 in a Box,
        int64 in a Discrete space).

    Raises:
        ValueError: If the action space is neither a bounded Box nor Discrete.
    """
    spec = EnvSpec(env) if isinstance(env, str) else env
    made = spec.make()
    space = made.action_space
    made.close()
    rng = np.random.default_rng(seed)
    if isinstance(space, gym.spaces.Discrete):
        n, start = int(space.n), int(space.start)

        def discrete(obs: np.ndarray) -> np.ndarray:
            return rng.integers(start, start + n, size=len(obs), dtype=np.int64)

        return discrete
    if not isinstance(space, gym.spaces.Box):
        raise ValueError(
            f"{spec.env_id} has action space {space}; random_policy_for needs a Box or Discrete"
        )
    uniform = UniformRandomPolicy(space.low.reshape(-1), space.high.reshape(-1))

    def policy(obs: np.ndarray) -> np.ndarray:
        action, _ = uniform.sample(len(obs), rng)
        return action.reshape(len(obs), *space.shape)

    return policy


@ray.remote(num_cpus=0.25)
class Evaluator:
    """Runs `episodes` deterministic episodes of a behaviour's greedy policy (no exploration)."""

    def __init__(self, *, env: EnvSpec, behaviour: Behaviour, seed: int) -> None:
        self.reset(env=env, behaviour=behaviour, seed=seed)

    def reset(self, *, env: EnvSpec, behaviour: Behaviour, seed: int) -> None:
        """Scores another run's policies from here on: its environment, behaviour and seed
        (nothing of the last run stays: `evaluate` makes its environments each time)."""
        self.env, self.seed = env, seed
        self.behaviour = behaviour

    def evaluate(
        self, weights: WeightArrays, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Evaluation:
        """Returns mean and std of the returns of episodes `first`, ..., `first` +
        `episodes` − 1 (reset seeds from the evaluator's seed + `first`), echoing `tag` back.

        `stats` carries what the behaviour counted while acting greedily (e.g. how often
        each option ran) and the means of the environment's own episode metrics.
        """
        self.behaviour.load(weights)
        self.behaviour.stats()  # drop anything counted before these weights
        played = play_episodes(
            self.behaviour.greedy, env=self.env, episodes=episodes, seed=self.seed + first
        )
        return {
            "tag": tag,
            "mean": float(played.returns.mean()),
            "std": float(played.returns.std()),
            "returns": [float(r) for r in played.returns],
            "stats": {**played.metric_means(), **self.behaviour.stats()},
        }


class RemoteEvaluator:
    """The learner's `Evaluator` (service/core.py): an `Evaluator` Ray actor runs the episodes.

    An evaluator that dies, or whose environment loses its world (a `ConnectionError`: a
    Minecraft client or world server gone), is replaced by a new one (up to `max_restarts`
    times) and the evaluations it held are started again there: episodes are seeded, so
    the result is the same. `restarts` counts the replacements; `on_restart` hears of each
    in one line. Any other error of an evaluation is the run's.
    """

    def __init__(
        self,
        *,
        env: EnvSpec,
        behaviour: Behaviour,
        seed: int,
        options: Optional[dict[str, Any]] = None,
        max_restarts: int = 0,
        on_restart: Optional[Callable[[str], None]] = None,
        kept: Any = None,
    ) -> None:
        """``kept``: an idle `Evaluator` actor of the same ``options`` (a finished run's,
        `release`) to score with, reset to this ``env``, ``behaviour`` and ``seed``; a new
        one starts instead if it is gone or still busy."""
        self._args = {"env": env, "behaviour": behaviour, "seed": seed}
        self._options = dict(options or {})
        self.max_restarts, self.restarts = max_restarts, 0
        self._on_restart = on_restart
        self._lock = threading.Lock()
        self._closed = False  # after close(), a dead evaluator is not replaced
        self._actor = self._start() if kept is None else self._adopt(kept)

    def _start(self) -> Any:
        # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
        return Evaluator.options(**self._options).remote(**self._args)  # type: ignore[attr-defined]

    def _adopt(self, kept: Any) -> Any:
        reset = kept.reset.remote(**self._args)
        try:
            if ray.wait([reset], timeout=ADOPT_S)[0]:
                ray.get(reset)
                return kept
        except RayActorError:  # it died while kept
            return self._start()
        ray.kill(kept)  # still scoring a finished run's last evaluation
        return self._start()

    def evaluate(
        self, weights: Weights, *, episodes: int, tag: EvalTag, first: int = 0
    ) -> Future[Evaluation]:
        """Starts the episodes in the actor (sent as numpy arrays) and returns at once."""
        result: Future[Evaluation] = Future()
        self._submit(as_arrays(weights), episodes, first, tag, result)
        return result

    def _submit(
        self,
        weights: WeightArrays,
        episodes: int,
        first: int,
        tag: EvalTag,
        result: Future[Evaluation],
    ) -> None:
        actor = self._actor
        ref: ObjectRef[Evaluation] = actor.evaluate.remote(
            weights, episodes=episodes, tag=tag, first=first
        )

        def retry(error: Exception) -> None:
            try:
                self._replace(actor, error)
                self._submit(weights, episodes, first, tag, result)
            except BaseException as failed:
                result.set_exception(failed)

        def done(future: Future[Evaluation]) -> None:
            try:
                result.set_result(future.result())
            except (RayActorError, RayTaskError) as error:
                if isinstance(error, RayTaskError) and not isinstance(error.cause, ConnectionError):
                    result.set_exception(error)
                    return
                # Ray calls this on a thread of its own, which must not wait on Ray (a new
                # actor, a kill): the replacement starts from a thread of ours.
                threading.Thread(target=retry, args=(error,), daemon=True).start()
            except BaseException as error:
                result.set_exception(error)

        ref.future().add_done_callback(done)

    def close(self) -> None:
        """Ends the evaluator actor now (its CPU share is free at once for the next run)."""
        ray.kill(self.release())

    def release(self) -> Any:
        """Stops using the evaluator actor (one that dies is not replaced any more) and
        returns it, alive, for another run to adopt (``kept``)."""
        with self._lock:
            self._closed = True
            return self._actor

    def _replace(self, dead: Any, error: Exception) -> None:
        """A new evaluator for `dead`, unless another evaluation already replaced it."""
        cause = error.cause if isinstance(error, RayTaskError) else error
        first = str(cause).strip().splitlines()[0] if str(cause).strip() else "died"
        what = "lost its world" if isinstance(cause, ConnectionError) else "died"
        with self._lock:
            if self._closed:
                raise RuntimeError("the evaluator was closed") from error
            if self._actor is not dead:
                return
            if self.restarts >= self.max_restarts:
                raise RuntimeError(
                    f"the evaluator {what} ({first}) after {self.restarts} restarts "
                    f"(evaluator.max_restarts={self.max_restarts})"
                ) from error
            self.restarts += 1
            ray.kill(dead)
            self._actor = self._start()
        if self._on_restart is not None:
            self._on_restart(
                f"evaluator {what} ({first}); restarted it (evaluator restart {self.restarts})"
            )
