"""The replay tables of a run: one per phase of the algorithm, each with the rate limiter
that holds its update ratio, for the preset's observation space and behaviour columns."""

from __future__ import annotations

from typing import Any, Optional

import numpy as np

from actors.transitions import replay_signature
from graft.config import TrainConfig
from graft.registry import make_builder
from learner.agent import Phase
from service.core import Behaviour


def table_spec(
    phase: Phase,
    *,
    signature: dict[str, Any],
    max_size: int,
    slack_env_steps: int,
    seed: Optional[int] = None,
) -> dict[str, Any]:
    """The replay table of one phase, its rate limiter holding the phase's update ratio
    and its sampler seeded with `seed` (None: fresh entropy)."""
    if phase.samples_per_insert is None:
        limiter: dict[str, Any] = {"kind": "min_size", "min_size": phase.min_size}
    else:
        limiter = {
            "kind": "sample_to_insert_ratio",
            "samples_per_insert": phase.samples_per_insert,
            "min_size": phase.min_size,
            "error_buffer": slack_env_steps * phase.samples_per_insert,
            "sample_credit": phase.sample_credit,
        }
    spec = {"name": phase.name, "max_size": max_size, "signature": signature}
    if seed is not None:
        spec["seed"] = seed
    if phase.sequence_length > 1:
        spec["max_sequence_length"] = phase.sequence_length
    return {**spec, "rate_limiter": limiter}


def signature_of(config: TrainConfig, behaviour: Behaviour) -> dict[str, Any]:
    env = config.make_env()
    signature = replay_signature(env.observation_space, behaviour.columns())
    env.close()
    return signature


def preset_tables(
    config: TrainConfig,
    *,
    phases: Optional[list[Phase]] = None,
    signature: Optional[dict[str, Any]] = None,
) -> list[dict[str, Any]]:
    """Every replay table a preset's run uses, one per phase (built when not given)."""
    if phases is None or signature is None:
        builder = make_builder(config)
        behaviour = builder.make_behaviour(num_actors=config.num_actors)
        phases, signature = builder.phases(), signature_of(config, behaviour)
    return [
        table_spec(
            p,
            signature=signature,
            max_size=config.replay_max_size,
            slack_env_steps=config.slack_env_steps,
            seed=int(np.random.SeedSequence([config.seed, i]).generate_state(1)[0]),
        )
        for i, p in enumerate(phases)
    ]


def transition_table_spec(config: TrainConfig) -> dict[str, Any]:
    """The table of a preset's last (online) phase, e.g. for `graft replay serve --preset`."""
    return preset_tables(config)[-1]
