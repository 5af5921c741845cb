"""Which world each actor environment and the evaluator play in.

Without `clients`, every environment of a Minecraft preset starts its own simulated world
server, in its actor's process and so on its actor's node (`--clients N` sets the number
of actors). With `clients` (or `clients_file`), each environment of each actor plays in
one listed Minecraft (Malmo) client (actor i's `envs_per_actor` environments in clients
i·k … i·k + k − 1) and the evaluator in the next: a client runs one mission at a time,
and a second one started in it replaces the first.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from actors.task import EnvSpec
from graft.config import TrainConfig
from graft.validation import ConfigError


def _read_file(path: str) -> list[str]:
    """``host:port`` lines of a clients file; blank lines and ``#`` comments skipped."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ConfigError(f"clients_file={path!r} cannot be read: {e.strerror}") from None
    lines = (line.split("#", 1)[0].strip() for line in text.splitlines())
    return [line for line in lines if line]


def _check_address(field: str, address: str) -> None:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(f"{field}={address!r} is not host:port (e.g. 10.0.0.5:9000)")


def world_clients(config: TrainConfig) -> list[str]:
    """The clients a run plays in: `envs_per_actor` per actor, then the evaluator's; []
    when every environment starts its own simulated world.

    Raises:
        ConfigError: in one line, before anything starts: a malformed or repeated client,
            fewer clients than the actors' environments plus the evaluator, or one
            `env_kwargs.address` that every actor would share.
    """
    source = "clients_file" if config.clients_file else "clients"
    listed = _read_file(config.clients_file) if config.clients_file else list(config.clients)
    if not listed:
        if "address" in config.env_kwargs:
            raise ConfigError(
                f"env_kwargs.address={config.env_kwargs['address']!r} would put all "
                f"{config.num_actors} actors and the evaluator in one world, each new mission "
                "replacing the last; list one client per actor and one for the evaluator in "
                "`clients` (host:port list) or `clients_file`"
            )
        return []
    seen: dict[str, int] = {}
    for i, address in enumerate(listed):
        _check_address(f"{source}[{i}]", address)
        key = address.lower()
        if key in seen:
            raise ConfigError(
                f"{source}: {address} is listed twice (entries {seen[key]} and {i}); a client "
                "plays one mission at a time, so two actors cannot share it"
            )
        seen[key] = i
    if "address" in config.env_kwargs:
        raise ConfigError(f"env_kwargs.address and {source} both name worlds; keep {source}")
    k = config.envs_per_actor
    need = config.num_actors * k + 1
    if len(listed) < need:
        players = f"{config.num_actors} actors" + (f" x {k} environments" if k > 1 else "")
        fewer = f" (or --actors {(len(listed) - 1) // k})" if len(listed) > k else ""
        raise ConfigError(
            f"{source}: {len(listed)} client{'s' * (len(listed) != 1)} for {players} and the "
            f"evaluator; need {need}{fewer}"
        )
    return listed[:need]


def actor_env(config: TrainConfig, clients: list[str], actor: int) -> EnvSpec | list[EnvSpec]:
    """Actor `actor`'s environments: each in a client of its own (`envs_per_actor`
    consecutive ones), else each in its own simulated world."""
    if not clients:
        return config.env_spec()
    k = config.envs_per_actor
    return [_in(config.env_spec(), address) for address in clients[actor * k : (actor + 1) * k]]


def evaluator_env(config: TrainConfig, clients: list[str]) -> EnvSpec:
    """The evaluator's environment: the last client, else its own simulated world."""
    return _in(config.env_spec(), clients[-1] if clients else None)


def _in(spec: EnvSpec, address: str | None) -> EnvSpec:
    if address is None:
        return spec
    return dataclasses.replace(spec, env_kwargs={**spec.env_kwargs, "address": address})
