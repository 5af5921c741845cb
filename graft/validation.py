"""One-line refusals of values a run cannot use, found before any process starts.

Each message names the field, the value and what is allowed (``td3.batch_size='abc' must be
an integer``); the CLI prints it as is and exits with status 2, never with a traceback.
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import math
import types
import typing
import warnings
from collections.abc import Iterable, Mapping
from typing import Any, Optional, Union

import yaml


class ConfigError(ValueError):
    """A value a run cannot use, said in one line naming the field, the value and what is
    allowed."""


class _Mismatch(Exception):
    """A value of the wrong type; the argument says what the field takes."""


def coerce(name: str, value: Any, hint: Any) -> Any:
    """``value`` as a field annotated ``hint`` takes it (a number written ``1e-3``, which
    YAML reads as a string, becomes a float).

    Raises:
        ConfigError: the value does not have the field's type, e.g.
            ``td3.batch_size='abc' must be an integer``.
    """
    try:
        return _coerce(value, hint)
    except _Mismatch as m:
        raise ConfigError(f"{name}={value!r} must be {m.args[0]}") from None


def _coerce(value: Any, hint: Any) -> Any:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        if _nonfinite(value) and any(a in (int, float) for a in args):
            raise _Mismatch("a finite number" + (" or null" if type(None) in args else ""))
        for option in (a for a in args if a is not type(None)):
            try:
                return _coerce(value, option)
            except _Mismatch:
                continue
        raise _Mismatch(describe(hint))
    if hint is bool:
        if isinstance(value, bool):
            return value
        raise _Mismatch(describe(hint))
    if hint in (int, float):
        number = _number(value)
        if _nonfinite(value):  # nan passes every range check (nan < 0 is False)
            raise _Mismatch("a finite number")
        if number is None or (hint is int and not float(number).is_integer()):
            raise _Mismatch(describe(hint))
        return int(number) if hint is int else number
    if hint is str:
        if isinstance(value, str):
            return value
        raise _Mismatch(describe(hint))
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise _Mismatch(describe(hint))
        item = args[0] if args else Any
        try:
            items = [_coerce(v, item) for v in value]
        except _Mismatch:
            raise _Mismatch(describe(hint)) from None
        return origin(items)
    if origin in (dict, Mapping) or hint in (dict, Mapping):
        if isinstance(value, Mapping):
            return value
        raise _Mismatch(describe(hint))
    if isinstance(hint, type) and dataclasses.is_dataclass(hint) and isinstance(value, hint):
        return value
    return value  # an annotation this check does not know: the dataclass decides


def _nonfinite(value: Any) -> bool:
    """Whether `value` reads as a number that is not finite (nan, inf, -inf, 1e999)."""
    number = _number(value)
    return isinstance(number, float) and not math.isfinite(number)


def _number(value: Any) -> Optional[float]:
    """``value`` as an int or float, or None; booleans are not numbers here."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        return value
    if isinstance(value, str):
        try:
            number = float(value.strip().replace("_", ""))
        except ValueError:
            return None
        return int(number) if number.is_integer() and "." not in value else number
    return None


def describe(hint: Any) -> str:
    """What a field annotated ``hint`` takes, in words: 'an integer', 'a list of numbers'."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (Union, types.UnionType):
        options = [describe(a) for a in args if a is not type(None)]
        return " or ".join(options) + (" or null" if type(None) in args else "")
    if origin in (tuple, list):
        item = describe(args[0]) if args else "values"
        plural = {"an integer": "integers", "a number": "numbers", "a string": "strings"}
        return f"a list of {plural.get(item, item)}"
    if origin in (dict, Mapping) or hint in (dict, Mapping):
        return "a mapping of name: value"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        hint, getattr(hint, "__name__", str(hint))
    )


def unknown_fields(unknown: Iterable[str], known: Iterable[str], *, section: str = "") -> str:
    """``unknown field td3.batchsize (did you mean td3.batch_size?)``; the known names are
    listed when no close match is found."""
    known, prefix = sorted(known), f"{section}." if section else ""
    unknown = sorted(unknown)
    parts, all_close = [], True
    for key in unknown:
        close = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
        all_close &= bool(close)
        hint = f" (did you mean {' or '.join(prefix + c for c in close)}?)" if close else ""
        parts.append(f"{prefix}{key}{hint}")
    message = f"unknown field{'s' if len(unknown) > 1 else ''} {', '.join(parts)}"
    if not all_close:
        message += f"; {section + ' has' if section else 'fields are'}: {', '.join(known)}"
    return message


def yaml_error(where: str, error: yaml.YAMLError) -> ConfigError:
    """A YAML parse error as one line with its line and column (1-based)."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error).splitlines()[0]
    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return ConfigError(f"{where}: malformed YAML{at}: {problem}")


def check_env_id(env_id: str) -> None:
    """Refuses an environment id gymnasium cannot make, before any process starts.

    Accepted: a registered id (``Pendulum-v1``), gymnasium's ``package.module:Env-v0`` (the
    module registers ``Env-v0`` when imported) and an import string ``package.module:Name``
    naming an environment class or factory.

    Raises:
        ConfigError: e.g. ``env_id='Pendulm-v1' is not a registered gymnasium environment
            (did you mean Pendulum-v1?)``.
    """
    import gymnasium as gym

    if not isinstance(env_id, str) or not env_id:
        raise ConfigError(f"env_id={env_id!r} must be a gymnasium id or package.module:Name")
    if ":" in env_id:
        module_name, _, name = env_id.partition(":")
        module = _import(f"env_id={env_id!r}", module_name)
        if name in gym.envs.registry or env_id in gym.envs.registry or hasattr(module, name):
            return
        raise ConfigError(
            f"env_id={env_id!r}: module {module_name} neither registers a gymnasium "
            f"environment {name!r} nor defines {name}"
        )
    if env_id in gym.envs.registry:
        return
    close = difflib.get_close_matches(env_id, list(gym.envs.registry), n=3, cutoff=0.8)
    hint = f" (did you mean {' or '.join(close)}?)" if close else ""
    raise ConfigError(
        f"env_id={env_id!r} is not a registered gymnasium environment{hint}; give a registered "
        "id, package.module:Env-v0 or package.module:EnvClass"
    )


def resolve_import_string(field: str, value: Any) -> Any:
    """The object an import string ``package.module:name`` (or ``package.module:a.b``) names.

    Raises:
        ConfigError: not of that form, the module does not import, or it has no such name;
            e.g. ``hardcoded_policy='mypkg.trees:make' does not resolve: no module named
            'mypkg'``.
    """
    where = f"{field}={value!r}"
    if not isinstance(value, str) or value.count(":") != 1:
        raise ConfigError(f"{where} must be an import string package.module:name")
    module_name, _, attribute = value.partition(":")
    if not module_name or not attribute:
        raise ConfigError(f"{where} must be an import string package.module:name")
    found: Any = _import(where, module_name)
    for part in attribute.split("."):
        if not hasattr(found, part):
            raise ConfigError(f"{where} does not resolve: {module_name} has no {attribute}")
        found = getattr(found, part)
    return found


def _import(where: str, module_name: str) -> types.ModuleType:
    """Imports a user's module; any failure is one line naming the module and the error."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        raise ConfigError(
            f"{where} does not resolve: no module named {e.name!r} (is its package installed, "
            "or its folder on import_path?)"
        ) from None
    except Exception as e:  # the user's module itself fails: say where, in one line
        if isinstance(e, SyntaxError):
            at, first = f" ({e.filename}, line {e.lineno})", e.msg
        else:
            at, first = "", str(e).splitlines()[0] if str(e) else ""
        raise ConfigError(
            f"{where}: importing {module_name} raised {type(e).__name__}{at}: {first}"
        ) from None


# Modules that moved (graft 0.1 -> 0.2): an import string a user wrote with the old path
# keeps working for one release, with a warning naming the new one.
MOVED_MODULES = {"service.run": "graft", "actors.minecraft": "minecraft"}
IMPORT_STRING_FIELDS = ("env_id", "hardcoded_policy", "obs_wrapper")


def moved_import_string(field: str, value: Any) -> Any:
    """``value`` with a moved module's old path replaced by its new one (and a
    `DeprecationWarning` naming both); any other value as it is."""
    if not isinstance(value, str):
        return value
    for old, new in MOVED_MODULES.items():
        if value == old or value.startswith((old + ".", old + ":")):
            renamed = new + value[len(old) :]
            warnings.warn(
                f"{field}={value!r}: {old} moved to {new}; write {renamed!r} (the old path "
                "stops working in the next release)",
                DeprecationWarning,
                stacklevel=3,
            )
            return renamed
    return value
