"""The user's task, named by import strings: how every process builds the environment.

A preset names the environment by a gymnasium id (``Pendulum-v1``, or the registration
form ``package.module:Env-v0``) or by an import string ``package.module:Factory`` naming a
``gym.Env`` subclass or a function returning one; ``obs_wrapper`` optionally names a
gymnasium wrapper (or any function env -> env) applied to every environment graft makes.
Only these strings travel to Ray actors: each process resolves them itself, after putting
the run's import path on ``sys.path``, so nothing of the user's is ever pickled.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Optional

import gymnasium as gym


def add_import_path(import_path: Sequence[str]) -> None:
    """Prepends the folders of ``import_path`` to ``sys.path`` (those not on it yet)."""
    for folder in reversed(list(import_path)):
        if folder not in sys.path:
            sys.path.insert(0, folder)


def split_import_string(spec: str, what: str) -> tuple[str, str]:
    """``"package.module:name"`` as ``(module, name)``.

    Raises:
        ValueError: ``spec`` is not of that form (the message names ``what``).
    """
    module, sep, name = str(spec).partition(":")
    if not sep or not module or not name:
        raise ValueError(f"{what}={spec!r} is not an import string 'package.module:name'")
    return module, name


def import_object(spec: str, *, what: str, import_path: Sequence[str] = ()) -> Any:
    """The object an import string ``"package.module:name"`` names.

    Args:
        spec: The import string.
        what: The setting it came from, for error messages (e.g. ``hardcoded_policy``).
        import_path: Folders put on ``sys.path`` first.

    Raises:
        ValueError: Malformed string, a module that does not import, or no such name in it.
    """
    module_name, name = split_import_string(spec, what)
    add_import_path(import_path)
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ValueError(
            f"{what}={spec!r}: cannot import {module_name} ({error}); install the package "
            "or add its folder to import_path"
        ) from None
    if not hasattr(module, name):
        raise ValueError(f"{what}={spec!r}: module {module_name} has no {name!r}")
    return getattr(module, name)


def _factory(env_id: str, import_path: Sequence[str]) -> Optional[Any]:
    """The class or function ``env_id`` names when it is an import string, else None: a
    gymnasium id, possibly in the form ``module:Env-v0``, which ``gym.make`` resolves."""
    module_name, sep, name = env_id.partition(":")
    if not sep or not module_name or not name.isidentifier():
        return None
    add_import_path(import_path)
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ValueError(
            f"env_id={env_id!r}: cannot import {module_name} ({error}); install the package "
            "or add its folder to import_path"
        ) from None
    obj = getattr(module, name, None)
    return obj if callable(obj) else None


@dataclass(frozen=True)
class EnvSpec:
    """Everything needed to build the task's environment in any process (strings only)."""

    env_id: str
    """Gymnasium id, ``module:Env-v0`` registration form, or ``module:Factory``."""
    env_kwargs: Mapping[str, Any] = field(default_factory=dict)
    """Keyword arguments of ``gym.make`` or of the factory."""
    obs_wrapper: Optional[str] = None
    """Import string of a wrapper (or function env -> env) applied to every environment."""
    import_path: tuple[str, ...] = ()
    """Folders prepended to ``sys.path`` before anything is imported."""

    def make(self) -> gym.Env:
        """Builds one environment, wrapped by ``obs_wrapper`` when one is named.

        Raises:
            ValueError: An id or import string that does not resolve, ``env_kwargs`` the
                environment refuses, or a factory or wrapper that returns no environment.
        """
        add_import_path(self.import_path)
        kwargs = dict(self.env_kwargs)
        factory = _factory(self.env_id, self.import_path)
        try:
            env = factory(**kwargs) if factory is not None else gym.make(self.env_id, **kwargs)
        except TypeError as error:
            raise ValueError(
                f"env_kwargs {sorted(kwargs)} rejected by {self.env_id}: {error}"
            ) from error
        except (gym.error.DependencyNotInstalled, ImportError) as error:
            raise ValueError(missing_dependency(self.env_id, error)) from None
        except gym.error.Error as error:
            raise ValueError(
                f"env_id={self.env_id!r} is not a gymnasium id nor an import string "
                f"'package.module:Factory': {error}"
            ) from None
        _check_env(env, f"env_id={self.env_id!r}")
        if self.obs_wrapper is not None:
            wrapper = import_object(
                self.obs_wrapper, what="obs_wrapper", import_path=self.import_path
            )
            env = wrapper(env)
            _check_env(env, f"obs_wrapper={self.obs_wrapper!r}")
        return env


EXTRAS = {
    "box2d": "box2d",
    "mujoco": "mujoco",
    "classic_control": "classic-control",
    "toy_text": "toy-text",
}
"""gymnasium's environment folders (gymnasium.envs.<folder>) and the extras that install
what they need."""


def missing_dependency(env_id: str, error: BaseException) -> str:
    """One line for an environment that needs a package that is not installed: which one
    to install (gymnasium's extra for its own environments, e.g. ``pip install
    "gymnasium[box2d]"`` for LunarLander-v3, also when a factory of the user's makes it),
    then what the import said."""
    said = " ".join(str(error).split()) or type(error).__name__
    extra = _gymnasium_extra(env_id, error)
    if extra is None:
        return f"env_id={env_id!r} needs a package that is not installed: {said}"
    return (
        f"env_id={env_id!r} needs a dependency that is not installed: pip install "
        f'"gymnasium[{extra}]" ({said})'
    )


def _gymnasium_extra(env_id: str, error: BaseException) -> Optional[str]:
    """The gymnasium extra (``box2d``, ``mujoco``, ...) that installs what failed to import:
    the folder of the gymnasium environment module that raised, or of ``env_id``'s entry
    point; None for environments outside gymnasium."""
    modules = []
    tb = error.__traceback__
    while tb is not None:
        modules.append(str(tb.tb_frame.f_globals.get("__name__", "")))
        tb = tb.tb_next
    try:
        entry = gym.spec(env_id).entry_point
        modules.append(entry.split(":")[0] if isinstance(entry, str) else "")
    except (gym.error.Error, ImportError):
        pass
    for module in reversed(modules):
        parts = module.split(".")
        if len(parts) >= 3 and parts[:2] == ["gymnasium", "envs"] and parts[2] in EXTRAS:
            return EXTRAS[parts[2]]
    return None


def _check_env(env: Any, source: str) -> None:
    """Refuses anything without the gymnasium interface graft steps."""
    missing = [
        a for a in ("reset", "step", "observation_space", "action_space") if not hasattr(env, a)
    ]
    if missing:
        raise ValueError(
            f"{source} gave {type(env).__name__}, not a gymnasium environment (no {missing})"
        )
