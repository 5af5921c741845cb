"""Values that pass a field's own range check and fail later: each edge value of every
field's type is refused in one line before Ray starts, or accepted by every check a run
makes first (`check_run`), with every number finite. No run is started: the checks alone.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import pytest

from graft.config import SECTIONS, TrainConfig, load_preset, preset_names
from graft.orchestration.checks import check_run
from graft.orchestration.sizes import check_networks
from graft.validation import ConfigError
from service.memory import MemoryBudget

EDGES: dict[str, Any] = {
    "0": 0,
    "-1": -1,
    "nan": math.nan,
    "nan-text": "nan",
    "+inf": math.inf,
    "-inf": -math.inf,
    "huge": 10**30,
    "empty-list": [],
    "empty-text": "",
    "wrong-type": {"not": "this"},
}
SKIPPED = {"preset", "import_path"}
"""Set by the loader itself (the preset's name, its folder on the import path)."""
LOOSE_STRINGS = {"clients_file", "backbone.teacher", "pretrain.demos"}
"""Paths read when the run starts; a wrong one fails there, in one line of its own."""


def _fields() -> list[str]:
    names = []
    for f in dataclasses.fields(TrainConfig):
        if f.name in SKIPPED:
            continue
        if f.name in SECTIONS:
            names += [f"{f.name}.{g.name}" for g in dataclasses.fields(SECTIONS[f.name])]
        else:
            names.append(f.name)
    return names


def _numbers(value: Any) -> list[float]:
    if isinstance(value, bool):
        return []
    if isinstance(value, (int, float)):
        return [float(value)]
    if isinstance(value, dict):
        return [n for v in value.values() for n in _numbers(v)]
    if isinstance(value, (list, tuple)):
        return [n for v in value for n in _numbers(v)]
    return []


def _outcome(field: str, value: Any) -> str:
    """'refused: <line>' or 'accepted'; anything else raised fails the test."""
    try:
        check_run(load_preset("pendulum-td3", **{field: value}), "local")
    except ConfigError as error:
        return f"refused: {error}"
    return "accepted"


@pytest.mark.parametrize("field", _fields())
def test_every_edge_value_is_refused_in_one_line_or_accepted(field: str) -> None:
    problems = []
    for label, value in EDGES.items():
        try:
            outcome = _outcome(field, value)
        except Exception as error:  # noqa: BLE001 - exactly what this test looks for
            problems.append(f"{label}: {type(error).__name__}: {str(error)[:200]}")
            continue
        if outcome.startswith("refused"):
            if "\n" in outcome:
                problems.append(f"{label}: a refusal of several lines: {outcome!r}")
            continue
        config = load_preset("pendulum-td3", **{field: value})
        bad = [n for n in _numbers(config.to_dict()) if not math.isfinite(n)]
        if bad:
            problems.append(f"{label}: accepted with a number that is not finite: {bad}")
    assert not problems, f"{field}:\n" + "\n".join(problems)


def test_the_fields_fuzzed_cover_every_section() -> None:
    fuzzed = {name.partition(".")[0] for name in _fields()}
    assert set(SECTIONS) <= fuzzed
    assert {"td3.critic_lr", "td3.batch_size", "td3.hidden_sizes", "replay_max_size"} <= set(
        _fields()
    )


@pytest.mark.parametrize(
    ("field", "value", "expected"),
    [
        ("td3.critic_lr", "nan", "td3.critic_lr='nan' must be a finite number"),
        ("td3.actor_lr", math.inf, "td3.actor_lr=inf must be a finite number"),
        ("backbone.switch_margin", math.nan, "must be a finite number or null"),
        ("td3.batch_size", 100_000_000, "td3.batch_size=100000000 is larger than the replay"),
        ("replay_max_size", 2_000_000_000, "replay_max_size=2000000000: the run's replay tables"),
        ("steps_per_insert", 10**7, "steps_per_insert=10000000 x envs_per_actor=4: an actor's"),
    ],
)
def test_values_the_range_checks_passed_are_refused_naming_them(
    field: str, value: Any, expected: str
) -> None:
    outcome = _outcome(field, value)
    assert outcome.startswith("refused") and expected in outcome, outcome


def test_a_batch_over_the_message_limit_is_refused_with_the_most_that_fits() -> None:
    config = load_preset("pendulum-td3", replay_max_size=10**8, **{"td3.batch_size": 10**7})
    expected = (
        r"^td3.batch_size=10000000: a sampled batch .* over the replay server's 64.0 MiB "
        r"message limit; use at most \d+$"
    )
    with pytest.raises(ConfigError, match=expected):
        check_run(config, "local")


def test_networks_wider_than_the_memory_are_refused_before_any_is_built() -> None:
    config = load_preset("pendulum-td3", **{"td3.hidden_sizes": [100_000, 100_000]})
    with pytest.raises(ConfigError, match=r"^td3.hidden_sizes=\[100000, 100000\]: the learner"):
        check_run(config, "local")  # torch would try 40 GB for the actor alone
    small = MemoryBudget(2**20, "a 1 MiB test budget")
    check_networks(load_preset("pendulum-td3", **{"td3.hidden_sizes": [64]}), budget=small)
    with pytest.raises(ConfigError, match="over the memory budget 1.0 MiB"):
        check_networks(load_preset("pendulum-td3", **{"td3.hidden_sizes": [4096]}), budget=small)


@pytest.mark.parametrize("preset", [p for p in preset_names() if p != "pendulum-backbone-teacher"])
def test_every_shipped_preset_passes_the_checks(preset: str) -> None:
    """(pendulum-backbone-teacher needs a trained teacher run folder first.)"""
    check_run(load_preset(preset), "local")
