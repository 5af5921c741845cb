"""Starting a run's roles: the probe of its task, the replay servers, each actor's share of
the phases, and the settings they run with."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

import ray
import torch

from actors.env_actor import Segment
from graft.config import TrainConfig
from graft.orchestration.preflight import check_task
from graft.orchestration.tables import signature_of
from graft.registry import make_builder
from graft.replay_host.shards import RunReplay
from graft.validation import ConfigError
from learner.agent import Phase
from learner.device import CompileMode, resolve_compile, resolve_device

RETRIES_ACROSS_RESTART = 40
"""Retries of a replay call that finds no server (backoff up to 2 s: over a minute), so
actors and the learner wait out a replay server's restart."""

ACTOR_FINISH_S = 60.0
"""How long actors may take to send their last batches once the learner is done."""

PENDING_INSERTS = 8
"""Insert batches an actor may queue for a table that never holds inserts back."""


def start_replay(
    tables: list[dict[str, Any]],
    config: TrainConfig,
    *,
    host: str,
    token: Optional[str],
    run_dir: Path,
) -> RunReplay:
    """The run's replay servers (`replay.shards` of them), supervised, with clients that
    connect from any node (the node's address when they listen on the network)."""
    return RunReplay(
        tables,
        shards=config.replay.shards,
        host=host,
        port=config.replay.port,
        token=token,
        run_dir=run_dir,
        checkpoint_every_s=config.replay.checkpoint_every_s,
        max_restarts=config.replay.max_restarts,
        advertise=ray.util.get_node_ip_address() if host == "0.0.0.0" else None,
        # Resends keep their sequence numbers, so retrying through a restart doubles nothing.
        max_retries=RETRIES_ACROSS_RESTART,
    )


def actor_segments(phases: list[Phase], num_actors: int) -> list[Segment]:
    """Each actor's share of every phase's env steps (rounded up); with `num_actors=1`
    the whole phases, as actors drawing on a shared `StepBudget` are given them. A phase
    whose table holds a samples-per-insert ratio has each insert waited for, so the rate
    limiter paces acting; a `min_size` table takes a queue of inserts."""
    return [
        Segment(
            p.name,
            -(-p.env_steps // num_actors),
            -(-p.warmup_steps // num_actors),
            pending_inserts=0 if p.samples_per_insert is not None else PENDING_INSERTS,
        )
        for p in phases
        if p.env_steps > 0
    ]


def probe(config: TrainConfig) -> tuple[Any, Any, dict[str, Any]]:
    """The run's builder, its behaviour and the replay signature, built from one env probe.

    Raises:
        ConfigError: the env or an algorithm refuses the config (spaces, env_kwargs, a
            missing teacher), in one line.
    """
    import gymnasium as gym

    check_task(config)
    try:
        builder = make_builder(config)  # imports the task, refusing what the method cannot use
        behaviour = builder.make_behaviour(num_actors=config.num_actors)
        return builder, behaviour, signature_of(config, behaviour)
    except (ValueError, FileNotFoundError, gym.error.Error) as e:
        raise ConfigError(str(e).splitlines()[0] if str(e) else type(e).__name__) from None


def learner_device(config: TrainConfig) -> tuple[torch.device, CompileMode]:
    """The device and compile mode the preset's ``learner`` section means here.

    Raises:
        ConfigError: a CUDA device this process does not see, or CUDA graphs without one.
    """
    try:
        device = resolve_device(config.learner.device)
        compile_mode = resolve_compile(config.learner.compile, device)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    return device, compile_mode
