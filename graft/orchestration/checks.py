"""Every check a run passes before Ray starts, in one place: what `train_here` does
first, and what a test can call to learn whether a config is refused, without a run."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

from graft.config import TrainConfig
from graft.orchestration.clients import world_clients
from graft.orchestration.preflight import check_fits_locally
from graft.orchestration.roles import learner_device, probe
from graft.orchestration.sizes import check_networks, check_sizes
from graft.orchestration.tables import preset_tables
from learner.agent import Phase
from learner.device import CompileMode


@dataclass
class CheckedRun:
    """What the checks built on the way, which the run goes on with."""

    device: torch.device
    compile_mode: CompileMode
    clients: list[str]
    builder: Any
    behaviour: Any
    signature: dict[str, Any]
    phases: list[Phase]
    tables: list[dict[str, Any]]


def check_run(config: TrainConfig, address: str) -> CheckedRun:
    """Refuses, in one line and before Ray starts, a run this machine cannot hold: its
    actors' placement, its learner's device, its clients, its networks' and tables'
    memory, its batches against the message limit, its task's import strings and spaces.

    Raises:
        ConfigError: the first value refused, naming the field, the value and the limit.
    """
    check_fits_locally(config, address)
    device, compile_mode = learner_device(config)  # a GPU that is not here: refused
    clients = world_clients(config)
    check_networks(config)  # before the behaviour builds its policy network
    builder, behaviour, signature = probe(config)
    phases = builder.phases()
    # A phase's table does not depend on its budget: a resumed run serves the same one.
    tables = preset_tables(config, phases=phases, signature=signature)
    check_sizes(config, tables, batch_size=builder.batch_size)
    return CheckedRun(device, compile_mode, clients, builder, behaviour, signature, phases, tables)
