"""The user's hard-coded policy, named by an import string: a py_trees tree or a callable.

A preset's ``hardcoded_policy: package.module:factory`` names a factory that graft calls
with the keyword arguments ``observation_space`` and ``action_space`` (only those it
accepts). It returns either

* a py_trees tree (a ``py_trees.behaviour.Behaviour`` root or a ``BehaviourTree``),
  ticked once per observation: graft writes the observation to the blackboard key
  ``/graft/observation``, unsets ``/graft/action``, ticks, and reads the action the tree
  wrote to ``/graft/action``; or
* a callable ``obs -> action``, on one observation or on a batch ``[B, *obs_shape]``;
  a ``batched`` attribute says which, otherwise graft probes it once (below).

Every method sees the result as a `HardCodedPolicy`: batched, observations
``[B, *obs_shape]`` in, actions ``[B, *action_shape]`` out. `ImportedPolicy` builds it
lazily where it is called and pickles as its import string: trees do not pickle, and Ray
actors must not receive live objects of the user's.
"""

from __future__ import annotations

import copy
import inspect
from collections.abc import Callable, Iterator, Sequence
from types import FrameType, TracebackType
from typing import Any, Optional

import numpy as np
import py_trees
from gymnasium import spaces
from py_trees.common import Access

from actors.task import import_object

HardCodedPolicy = Callable[[np.ndarray], np.ndarray]
"""Batched deterministic policy: observations [B, *obs_shape] -> actions [B, *action_shape]."""

OBSERVATION_KEY = "/graft/observation"
"""Blackboard key graft writes the observation to before each tick of a tree."""

ACTION_KEY = "/graft/action"
"""Blackboard key a tree writes its action to; graft unsets it before each tick."""

PROBE_BATCH = 5
"""Sampled observations a callable is probed on to tell batched from one-at-a-time."""


def _action_dtype(action_space: spaces.Space) -> Any:
    return np.int64 if isinstance(action_space, spaces.Discrete) else np.float32


def _as_action(value: Any, action_space: spaces.Space, source: str) -> np.ndarray:
    """One action as an array of the action space's shape and graft's dtype."""
    shape = tuple(action_space.shape or ())
    array = np.asarray(value, dtype=_action_dtype(action_space))
    if array.size != int(np.prod(shape, dtype=np.int64)):
        raise ValueError(
            f"{source} returned an action of shape {array.shape}; the action space "
            f"{action_space} needs {list(shape)}"
        )
    return array.reshape(shape)


class _Adapter:
    """Shared part of the adapters: the spaces, batch handling and the shape checks."""

    def __init__(self, observation_space: spaces.Space, action_space: spaces.Space, name: str):
        self.observation_space, self.action_space, self.name = (
            observation_space,
            action_space,
            name,
        )
        self.obs_shape = tuple(observation_space.shape or ())

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """Actions for a batch [B, *obs_shape] (or one action for one observation)."""
        obs = np.asarray(obs)
        if obs.shape == self.obs_shape:
            return self._batch(obs[None])[0]
        if obs.shape[1:] != self.obs_shape:
            raise ValueError(
                f"observation has shape {obs.shape}; {self.name} expects "
                f"{list(self.obs_shape)} or [B, {', '.join(map(str, self.obs_shape))}]"
            )
        if len(obs) == 0:
            shape = (0, *(self.action_space.shape or ()))
            return np.zeros(shape, _action_dtype(self.action_space))
        return self._batch(obs)

    def _batch(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError


class TreePolicy(_Adapter):
    """A py_trees tree as a batched policy: one tick per observation (blackboard keys above)."""

    def __init__(
        self,
        tree: py_trees.behaviour.Behaviour | py_trees.trees.BehaviourTree,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        *,
        name: str = "the tree",
    ) -> None:
        """Sets the tree up (``setup()`` on every node, once) and attaches graft's client.

        Args:
            tree: The root behaviour, or a ``BehaviourTree`` (kept as is, with its visitors).
            observation_space: Space of the observations it is ticked on.
            action_space: Space of the actions it writes.
            name: Shown in error messages (the import string).
        """
        super().__init__(observation_space, action_space, name)
        if not isinstance(tree, py_trees.trees.BehaviourTree):
            tree = py_trees.trees.BehaviourTree(tree)
        self.tree = tree
        self.tree.setup()
        self._blackboard = py_trees.blackboard.Client(name="graft")
        self._blackboard.register_key(OBSERVATION_KEY, access=Access.WRITE)
        self._blackboard.register_key(ACTION_KEY, access=Access.WRITE)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        """Ticks the tree once on one observation and returns the action it wrote.

        Raises:
            RuntimeError: The tick wrote no action to ``/graft/action``.
        """
        self._blackboard.set(OBSERVATION_KEY, obs)
        self._blackboard.unset(ACTION_KEY)
        self.tree.tick()
        if not self._blackboard.exists(ACTION_KEY):
            raise RuntimeError(
                f"{self.name}: the tick ended {self.tree.root.status.value} on "
                f"{self.tree.root.name!r} without writing {ACTION_KEY}; every tick must write "
                "an action"
            )
        return _as_action(self._blackboard.get(ACTION_KEY), self.action_space, self.name)

    def _batch(self, obs: np.ndarray) -> np.ndarray:
        return np.stack([self.act_one(row) for row in obs])


class CallablePolicy(_Adapter):
    """A callable as a batched policy, called on the whole batch or once per observation."""

    def __init__(
        self,
        policy: Callable[[np.ndarray], Any],
        observation_space: spaces.Space,
        action_space: spaces.Space,
        *,
        batched: Optional[bool] = None,
        name: str = "the policy",
    ) -> None:
        """Wraps ``policy``.

        Args:
            policy: ``obs -> action``, on one observation or on a batch.
            observation_space: Space of its observations (probe samples come from a copy).
            action_space: Space of its actions.
            batched: True: call it on batches; False: once per observation; None: the
                callable's own ``batched`` attribute, else probe it (`probe_batched`).
            name: Shown in error messages (the import string).
        """
        super().__init__(observation_space, action_space, name)
        self.policy = policy
        if batched is None:
            batched = getattr(policy, "batched", None)
        if batched is None:
            batched = probe_batched(policy, observation_space, action_space)
        self.batched = bool(batched)

    def _batch(self, obs: np.ndarray) -> np.ndarray:
        if not self.batched:
            return np.stack(
                [_as_action(self.policy(row), self.action_space, self.name) for row in obs]
            )
        out = np.asarray(self.policy(obs), dtype=_action_dtype(self.action_space))
        shape = (len(obs), *(self.action_space.shape or ()))
        if out.size != int(np.prod(shape, dtype=np.int64)):
            raise ValueError(
                f"{self.name} returned actions of shape {out.shape} for {len(obs)} "
                f"observations; expected {list(shape)}"
            )
        return out.reshape(shape)


def probe_batched(
    policy: Callable[[np.ndarray], Any],
    observation_space: spaces.Space,
    action_space: spaces.Space,
) -> bool:
    """Whether ``policy`` acts on batches: called on `PROBE_BATCH` sampled observations,
    it returns one action per row, equal to what it returns on each row alone.

    The samples come from a seeded copy of the space (no global random state is
    touched). A callable that fails on the batch, returns another shape or other actions
    (e.g. because it keeps state) is called once per observation.
    """
    space = copy.deepcopy(observation_space)
    space.seed(0)
    obs = np.stack([np.asarray(space.sample()) for _ in range(PROBE_BATCH)])
    try:
        singles = np.stack([_as_action(policy(row), action_space, "") for row in obs])
    except Exception:  # noqa: BLE001 - a callable that only takes batches
        singles = None
    try:
        batch = np.asarray(policy(obs), dtype=_action_dtype(action_space))
        batch = batch.reshape(PROBE_BATCH, *(action_space.shape or ()))
    except Exception:  # noqa: BLE001 - a callable that only takes one observation
        return False
    if singles is None:
        return True
    return bool(np.allclose(batch, singles, equal_nan=True))


def _call_factory(
    factory: Callable[..., Any], observation_space: spaces.Space, action_space: spaces.Space
) -> Any:
    """Calls the factory with ``observation_space`` / ``action_space``, those it accepts."""
    offered = {"observation_space": observation_space, "action_space": action_space}
    try:
        parameters = inspect.signature(factory).parameters.values()
    except (TypeError, ValueError):  # no signature (some builtins): offer nothing
        return factory()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters):
        return factory(**offered)
    names = {p.name for p in parameters}
    return factory(**{k: v for k, v in offered.items() if k in names})


def make_hardcoded_policy(
    spec: str,
    observation_space: spaces.Space,
    action_space: spaces.Space,
    *,
    import_path: Sequence[str] = (),
) -> HardCodedPolicy:
    """Imports the factory ``spec`` names, calls it and adapts what it returns.

    Raises:
        ValueError: The import string does not resolve, or the factory returns neither a
            py_trees tree nor a callable.
    """
    factory = import_object(spec, what="hardcoded_policy", import_path=import_path)
    if not callable(factory):
        raise ValueError(
            f"hardcoded_policy={spec!r} names a {type(factory).__name__}, not a factory"
        )
    made = _call_factory(factory, observation_space, action_space)
    if isinstance(made, py_trees.behaviour.Behaviour | py_trees.trees.BehaviourTree):
        return TreePolicy(made, observation_space, action_space, name=spec)
    if callable(made):
        return CallablePolicy(made, observation_space, action_space, name=spec)
    raise ValueError(
        f"hardcoded_policy={spec!r} returned a {type(made).__name__}; the factory must return "
        "a py_trees tree (its root behaviour) or a callable obs -> action"
    )


class ImportedPolicy:
    """A hard-coded policy built on first use from its import string, in whatever process
    calls it; it pickles as the string (and the spaces), never as the built tree."""

    def __init__(
        self,
        spec: str,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        *,
        import_path: Sequence[str] = (),
    ) -> None:
        self.spec = spec
        self.observation_space, self.action_space = observation_space, action_space
        self.import_path = tuple(import_path)
        self._policy: Optional[HardCodedPolicy] = None

    def build(self) -> HardCodedPolicy:
        """The adapted policy, built once per process (errors surface here)."""
        if self._policy is None:
            self._policy = make_hardcoded_policy(
                self.spec, self.observation_space, self.action_space, import_path=self.import_path
            )
        return self._policy

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.build()(obs)

    def __getstate__(self) -> dict[str, Any]:
        return {**self.__dict__, "_policy": None}


def required_policy(
    spec: Optional[str],
    observation_space: spaces.Space,
    action_space: spaces.Space,
    *,
    method: str,
    import_path: Sequence[str] = (),
) -> ImportedPolicy:
    """The hard-coded policy a method builds on, built once here so that a bad import
    string or factory is reported before any actor starts.

    Raises:
        ValueError: No policy named (the message names the method), or it does not build.
    """
    if not spec:
        raise ValueError(
            f"{method} improves a hard-coded policy, and the preset names none: set "
            "hardcoded_policy: package.module:factory (a py_trees tree or a callable)"
        )
    policy = ImportedPolicy(spec, observation_space, action_space, import_path=import_path)
    check_acts(policy.build(), observation_space, name=spec)
    return policy


def check_acts(policy: HardCodedPolicy, observation_space: spaces.Space, *, name: str) -> None:
    """Calls ``policy`` once on an observation sampled from a seeded copy of the task's
    observation space, so that a policy written for another task fails here, before any
    actor starts, rather than in every actor.

    Raises:
        ValueError: One line: for a tree, the leaf that raised (its name and class), the
            error and the observation's shape; graft's own refusals (no action written,
            an action of the wrong shape) as they are.
    """
    space = copy.deepcopy(observation_space)
    space.seed(0)
    obs = np.asarray(space.sample())
    try:
        policy(obs)
    except Exception as error:  # noqa: BLE001 - the user's code: say where, in one line
        frames = list(_frames(error.__traceback__))
        if frames and frames[-1].f_code.co_filename == __file__:
            raise  # graft's adapter refused what the policy returned: already one line
        said = " ".join(str(error).split())
        leaf = next(
            (
                f"leaf {who.name!r} ({type(who).__name__}) "
                for who in (f.f_locals.get("self") for f in reversed(frames))
                if isinstance(who, py_trees.behaviour.Behaviour)
            ),
            "",
        )
        raise ValueError(
            f"hardcoded_policy={name!r} fails on the task's observations: {leaf}raised "
            f"{type(error).__name__}: {said} on an observation of shape {obs.shape}"
        ) from None


def _frames(tb: Optional[TracebackType]) -> Iterator[FrameType]:
    """The frames of a traceback, outermost first."""
    while tb is not None:
        yield tb.tb_frame
        tb = tb.tb_next
