"""Sizes a run's config implies, checked against the machine before Ray starts: the
replay tables against the memory budget, the batch against the table and the gRPC message
limit, the networks' widths against the memory budget.

Each passes the config's own range checks (a batch of 10**8 is a positive integer) and
would fail later, after Ray and the replay server started, with a traceback from gRPC,
numpy or torch. Each is refused here in one line naming the field, what it implies and
the limit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Optional

from graft.config import TrainConfig
from graft.orchestration.preflight import check_task
from graft.validation import ConfigError
from service.memory import MemoryBudget, gib, memory_budget
from service.replay.codec import DEFAULT_MAX_BYTES
from service.replay.server.request_limits import RESPONSE_OVERHEAD_BYTES
from service.replay.server.samplers import Prioritized, make_sampler
from service.replay.server.signature import Signature
from service.replay.server.table_memory import item_bytes, sampled_bytes, table_bytes

NETWORK_COPIES = 5
"""Copies of each network's parameters a learner holds: the weights, the target network,
the gradients and Adam's two moments."""
ACTIVATION_COPIES = 2
"""Copies of a batch's activations an update holds: the forward pass's, kept for the
backward pass, and their gradients."""


def check_sizes(
    config: TrainConfig,
    tables: Sequence[dict[str, Any]],
    *,
    batch_size: int,
    budget: Optional[MemoryBudget] = None,
) -> None:
    """Refuses tables this machine cannot hold and batches no message can carry, before
    anything starts, nor an update's activations (`check_networks` has checked the
    networks themselves before they were built).

    Raises:
        ConfigError: e.g. ``td3.batch_size=100000000: a sampled batch of transitions
            takes 7.4 GiB, over the replay server's 64 MiB message limit; ...``.
    """
    budget = budget or memory_budget()
    check_tables(config, tables, budget)
    check_batch(config, tables, batch_size)
    check_activations(config, tables[-1]["signature"], batch_size, budget)


def check_tables(
    config: TrainConfig, tables: Sequence[dict[str, Any]], budget: MemoryBudget
) -> None:
    """The run's replay tables at ``replay_max_size`` against the memory budget (the
    replay server checks the same when it starts, `table_config.make_tables`)."""
    need = sum(_table_bytes(t) for t in tables)
    if need > budget.bytes:
        per_item = _item_bytes(tables[-1])
        raise ConfigError(
            f"replay_max_size={config.replay_max_size}: the run's replay tables need "
            f"{gib(need)} at max_size ({per_item} B an item), over the memory budget "
            f"{budget}; lower replay_max_size"
        )


def check_batch(config: TrainConfig, tables: Sequence[dict[str, Any]], batch_size: int) -> None:
    """The batch against the table it is drawn from and the gRPC message that carries it,
    and an actor's insert (``steps_per_insert`` x ``envs_per_actor`` items) against it."""
    field = _batch_field(config)
    if batch_size > config.replay_max_size:
        raise ConfigError(
            f"{field}={batch_size} is larger than the replay table "
            f"(replay_max_size={config.replay_max_size}): every batch would repeat items"
        )
    room = DEFAULT_MAX_BYTES - RESPONSE_OVERHEAD_BYTES
    insert = config.steps_per_insert * config.envs_per_actor
    per_insert = Signature.from_dict(tables[-1]["signature"]).item_bytes
    if insert * per_insert > room:
        raise ConfigError(
            f"steps_per_insert={config.steps_per_insert} x envs_per_actor="
            f"{config.envs_per_actor}: an actor's insert of {insert} items takes "
            f"{gib(insert * per_insert)}, over the replay server's {gib(DEFAULT_MAX_BYTES)} "
            f"message limit; insert at most {room // per_insert} items at a time"
        )
    for table in tables:
        k = int(table.get("max_sequence_length", 1))
        per_item = Signature.from_dict(table["signature"]).item_bytes
        need = sampled_bytes(per_item, batch_size, k)
        if need > room:
            most = room // sampled_bytes(per_item, 1, k)
            raise ConfigError(
                f"{field}={batch_size}: a sampled batch of table {table['name']} takes "
                f"{gib(need)}, over the replay server's {gib(DEFAULT_MAX_BYTES)} message "
                f"limit; use at most {most}"
            )


def check_networks(config: TrainConfig, *, budget: Optional[MemoryBudget] = None) -> None:
    """The learner's networks (``hidden_sizes``) against the memory budget, before any is
    built (an actor's behaviour builds its policy network): a lower bound on what their
    parameters, targets, gradients and Adam's moments take, and then one batch's
    activations (naming the batch when the networks alone fit).

    Raises:
        ConfigError: e.g. ``td3.hidden_sizes=[100000, 100000]: the learner's networks take
            at least 558.8 GiB (...), over the memory budget 21.2 GiB (...)``.
    """
    import gymnasium as gym

    budget = budget or memory_budget()
    check_task(config, policy=False)
    try:
        env = config.make_env()
    except (ValueError, gym.error.Error) as e:  # as `probe` says it
        raise ConfigError(str(e).splitlines()[0] if str(e) else type(e).__name__) from None
    obs, act = gym.spaces.flatdim(env.observation_space), gym.spaces.flatdim(env.action_space)
    env.close()
    for section, nets in _networks(config, obs, act):
        widths = list(getattr(config, section).hidden_sizes)
        need = _network_bytes(nets)
        if need > budget.bytes:
            raise ConfigError(
                f"{section}.hidden_sizes={widths}: the learner's networks take at least "
                f"{gib(need)} ({NETWORK_COPIES} copies of each: weights, targets, gradients, "
                f"Adam's two moments), over the memory budget {budget}"
            )


def check_activations(
    config: TrainConfig, signature: dict[str, Any], batch_size: int, budget: MemoryBudget
) -> None:
    """One update's activations (batch x widths) with the networks, against the budget."""
    obs, act = (_width(signature, column) for column in ("obs", "action"))
    field = _batch_field(config)
    for section, nets in _networks(config, obs, act):
        widths = list(getattr(config, section).hidden_sizes)
        need = _network_bytes(nets)
        need += 4 * ACTIVATION_COPIES * batch_size * sum(widths) * len(nets)
        if need > budget.bytes:
            raise ConfigError(
                f"{field}={batch_size} with {section}.hidden_sizes={widths}: an update's "
                f"activations and the networks take at least {gib(need)}, over the memory "
                f"budget {budget}"
            )


def _networks(config: TrainConfig, obs: int, act: int) -> list[tuple[str, list[list[int]]]]:
    """The sections whose ``hidden_sizes`` the algorithm builds, and each network's layer
    widths (a lower bound where the algorithm adds inputs or heads)."""
    td3 = list(config.td3.hidden_sizes)
    dqn = list(config.dqn.hidden_sizes)
    actor, critic = [obs, *td3, act], [obs + act, *td3, 1]
    q = [obs, *dqn, 1]
    if config.algorithm == "ddqn":
        return [("dqn", [q])]
    found = [("td3", [actor, critic, critic])]
    if config.algorithm == "options":
        found.append(("dqn", [q]))
    return found


def _network_bytes(nets: list[list[int]]) -> int:
    return 4 * NETWORK_COPIES * sum(_parameters(dims) for dims in nets)


def _width(signature: dict[str, Any], column: str) -> int:
    shape = signature.get(column, {}).get("shape", [])
    return max(1, math.prod(int(d) for d in shape))


def _parameters(dims: list[int]) -> int:
    return sum((a + 1) * b for a, b in zip(dims, dims[1:], strict=False))


def _batch_field(config: TrainConfig) -> str:
    return "dqn.batch_size" if config.algorithm == "ddqn" else "td3.batch_size"


def _item_bytes(table: dict[str, Any]) -> int:
    return item_bytes(
        Signature.from_dict(table["signature"]),
        max_times_sampled=int(table.get("max_times_sampled", 0)),
        max_sequence_length=int(table.get("max_sequence_length", 1)),
        remover=table.get("remover", "fifo"),
    )


def _table_bytes(table: dict[str, Any]) -> int:
    prioritized = isinstance(make_sampler(table.get("sampler")), Prioritized)
    return table_bytes(int(table["max_size"]), _item_bytes(table), prioritized=prioritized)
