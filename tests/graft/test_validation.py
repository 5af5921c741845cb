"""The one-line checks behind the CLI: field types, import strings, environment ids."""

from __future__ import annotations

import json
import os
import sys
from typing import Any, Optional

import pytest

from graft.validation import ConfigError, check_env_id, coerce, resolve_import_string

COERCE = [
    # (annotation, value, expected)
    (int, 3, 3),
    (int, 2.0e4, 20_000),
    (int, "1e5", 100_000),
    (float, "1e-3", 1e-3),
    (float, 2, 2),
    (bool, False, False),
    (Optional[float], None, None),
    (Optional[str], "runs/teacher", "runs/teacher"),
    (tuple[int, ...], [64, 64], (64, 64)),
    (list[str], ["src", "."], ["src", "."]),
    (dict[str, Any], {"a": 1}, {"a": 1}),
]
REFUSED = [
    (int, "abc", "x='abc' must be an integer"),
    (int, 2.5, "x=2.5 must be an integer"),
    (int, True, "x=True must be an integer"),
    (float, "fast", "x='fast' must be a number"),
    (bool, "yes please", "x='yes please' must be true or false"),
    (str, 5, "x=5 must be a string"),
    (Optional[float], "x", "x='x' must be a number or null"),
    (tuple[int, ...], [64, "wide"], "x=[64, 'wide'] must be a list of integers"),
    (list[str], "src", "x='src' must be a list of strings"),
    (dict[str, Any], [1], "x=[1] must be a mapping of name: value"),
]


@pytest.mark.parametrize("hint, value, expected", COERCE)
def test_coerce_takes_values_of_the_fields_type(hint, value, expected) -> None:
    out = coerce("x", value, hint)
    assert out == expected and type(out) is type(expected)


@pytest.mark.parametrize("hint, value, message", REFUSED)
def test_coerce_refuses_naming_field_value_and_type(hint, value, message) -> None:
    with pytest.raises(ConfigError) as error:
        coerce("x", value, hint)
    assert str(error.value) == message


def test_import_string_resolves_to_the_named_object() -> None:
    assert resolve_import_string("hardcoded_policy", "json:dumps") is json.dumps
    assert resolve_import_string("obs_wrapper", "os:path.join") is os.path.join


@pytest.mark.parametrize(
    "value, message",
    [
        ("json", "hardcoded_policy='json' must be an import string package.module:name"),
        (":dumps", "hardcoded_policy=':dumps' must be an import string package.module:name"),
        ("json:nope", "hardcoded_policy='json:nope' does not resolve: json has no nope"),
        (
            "no_such_pkg.trees:make",
            "hardcoded_policy='no_such_pkg.trees:make' does not resolve: no module named "
            "'no_such_pkg' (is its package installed, or its folder on import_path?)",
        ),
    ],
)
def test_import_string_that_does_not_resolve_is_one_line(value, message) -> None:
    with pytest.raises(ConfigError) as error:
        resolve_import_string("hardcoded_policy", value)
    assert str(error.value) == message


def test_a_user_module_that_fails_to_import_is_named_with_its_line(tmp_path, monkeypatch):
    (tmp_path / "broken_task.py").write_text("x = 1\ndef make(:\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError) as error:
        resolve_import_string("hardcoded_policy", "broken_task:make")
    sys.modules.pop("broken_task", None)
    assert str(error.value) == (
        f"hardcoded_policy='broken_task:make': importing broken_task raised SyntaxError "
        f"({tmp_path / 'broken_task.py'}, line 2): invalid syntax"
    )


def test_env_ids_in_every_accepted_form() -> None:
    check_env_id("Pendulum-v1")  # registered
    check_env_id("minecraft.agent.travel_env:MinecraftTravel-v0")  # module registers it
    check_env_id("gymnasium.envs.classic_control:PendulumEnv")  # a class by import string
    with pytest.raises(ConfigError) as error:
        check_env_id("gymnasium.envs.classic_control:Pendulum-v9")
    assert str(error.value) == (
        "env_id='gymnasium.envs.classic_control:Pendulum-v9': module "
        "gymnasium.envs.classic_control neither registers a gymnasium environment "
        "'Pendulum-v9' nor defines Pendulum-v9"
    )
