"""What the `graft` commands share: usage errors and exit statuses, --address, --set."""

from __future__ import annotations

import os
import sys
from typing import Optional

DEFAULT_PRESET = "pendulum-td3"

INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), as shells report it."""
TERMINATED = 143
"""Exit status after SIGTERM (128 + SIGTERM), which stops a run as Ctrl-C does."""


class UsageError(SystemExit):
    """A bad command-line value: one line on stderr (main prints it), exit status 2."""

    def __init__(self, command: str, message: str) -> None:
        super().__init__(2)
        self.message = f"graft {command}: {message}"

    def __str__(self) -> str:
        return self.message


def at_least(command: str, flag: str, value: Optional[int], minimum: int) -> None:
    if value is not None and value < minimum:
        raise UsageError(command, f"{flag}={value} must be >= {minimum}")


def ray_address(command: str, given: Optional[str]) -> str:
    """The Ray address a run uses: --address, else RAY_ADDRESS, said in one line (it must
    not change a run silently), else 'local' (a new local Ray instance)."""
    if given is not None:
        return given
    from_env = os.environ.get("RAY_ADDRESS")
    if not from_env:
        return "local"
    print(
        f"graft {command}: joining the Ray cluster at RAY_ADDRESS={from_env}; --address "
        "local starts a new local Ray instead",
        file=sys.stderr,
    )
    return from_env


def set_overrides(command: str, pairs: list[str]) -> dict[str, object]:
    """`--set` pairs as preset overrides; a bad pair is `command`'s usage error."""
    from graft.validation import ConfigError

    try:
        return parse_settings(pairs)
    except ConfigError as error:
        raise UsageError(command, str(error)) from None


def parse_settings(pairs: list[str]) -> dict[str, object]:
    """`--set section.field=value` pairs as preset overrides (values parsed as YAML).

    Raises:
        ConfigError: a pair without '=' or a value that is not YAML.
    """
    import yaml

    from graft.validation import ConfigError

    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(
                f"--set {pair!r}: expected key=value, e.g. backbone.correction_limit=0.5"
            )
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as error:
            problem = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise ConfigError(
                f"--set {key.strip()}={value!r}: not a YAML value ({problem})"
            ) from None
    return out
