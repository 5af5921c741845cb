"""What a resumed run continues with: the learner checkpoint's state, and the phases left
once its replay table is known (restored from the run folder, or refilled)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Optional

from graft.config import TrainConfig
from graft.replay_host.folder import Restored
from graft.validation import ConfigError
from learner.agent import Phase
from learner.checkpoint import load_checkpoint
from learner.loop import FallsBack, LoopState, updates_allowed


def check_resumable(
    phases: list[Phase], state: LoopState, config: TrainConfig, *, refill: bool
) -> None:
    """Refuses a resume that cannot continue: several phases, or nothing left to train
    (with `refill`, the table must refill to `learning_starts` first)."""
    if len(phases) != 1:
        raise ValueError(
            f"resume is supported for single-phase algorithms; {config.algorithm} has "
            f"{len(phases)} phases (its pre-training data is not in the checkpoint)"
        )
    remaining = config.env_steps - state.env_steps
    refilling = config.learning_starts if refill else 0
    if remaining <= refilling:
        refilled = f" and refilling replay takes {refilling}" if refill else ""
        raise ValueError(
            f"nothing left to train: the checkpoint is at {state.env_steps} env steps, "
            f"the budget is {config.env_steps}{refilled}; raise --env-steps"
        )


def resumed_phases(
    phases: list[Phase],
    state: LoopState,
    config: TrainConfig,
    *,
    restored: Optional[Restored],
    batch_size: int,
) -> list[Phase]:
    """The phases left after a checkpoint.

    A fresh table (`restored` None) refills to `learning_starts` with the restored policy
    before updates resume. A restored table goes on at once: its inserts are the run's
    env steps (the actors act the rest of the budget) and its rate limiter, which counts
    its restored inserts and samples, sets how many updates are left. Updates the killed
    learner made after its last checkpoint are not made again: their samples are counted.
    """
    phase = phases[0]
    if restored is None:
        check_resumable(phases, state, config, refill=True)
        remaining = config.env_steps - state.env_steps
        more = int((remaining - config.learning_starts) * config.updates_per_env_step)
    else:
        remaining = max(config.env_steps - restored.env_steps, 0)
        if phase.samples_per_insert is None:
            more = int(remaining * config.updates_per_env_step)
        else:
            final = updates_allowed(phase, restored.inserts + remaining, batch_size=batch_size)
            more = max(final - -(-restored.samples // batch_size), 0)
        if remaining == 0 and more == 0:
            raise ValueError(
                f"nothing left to train: the replay table holds {restored.env_steps} env "
                f"steps of the budget of {config.env_steps}, and its rate limiter admits no "
                "more updates; raise --env-steps"
            )
    return [
        dataclasses.replace(
            phase, env_steps=remaining, warmup_steps=0, updates=state.updates + more
        )
    ]


def restore(
    algorithm: Any, checkpoint: Path, phases: list[Phase], config: TrainConfig, *, refill: bool
) -> LoopState:
    """The loop state of `checkpoint`, loaded into `algorithm`.

    Raises:
        ConfigError: the checkpoint does not fit the config, or nothing is left to train
            (with `refill`, after the table refilled).
    """
    saved = load_checkpoint(checkpoint)
    try:
        algorithm.load_state_dict(saved["algorithm"])
    except (RuntimeError, KeyError, ValueError) as e:
        first = str(e).splitlines()[0]
        raise ConfigError(
            f"--resume: {checkpoint} does not fit this config ({config.algorithm}, "
            f"{config.env_id}): {first}"
        ) from None
    if isinstance(algorithm, FallsBack):
        # The run learns on: whether it ends on the tree is decided again when it stops.
        algorithm.tree_only = False
    state = LoopState(**saved["loop"])
    try:
        check_resumable(phases, state, config, refill=refill)
    except ValueError as e:
        raise ConfigError(f"--resume: {e}") from None
    return state


def resume_with(
    phases: list[Phase],
    state: LoopState,
    config: TrainConfig,
    restored: Optional[Restored],
    batch_size: int,
) -> list[Phase]:
    """The phases left for a resumed run, said in one line; with a restored table the
    state's env steps become the table's.

    Raises:
        ConfigError: nothing is left to train.
    """
    try:
        phases = resumed_phases(phases, state, config, restored=restored, batch_size=batch_size)
    except ValueError as e:
        raise ConfigError(f"--resume: {e}") from None
    if restored is not None:
        state.env_steps = restored.env_steps
        print(
            f"replay table restored: {restored.size:,} items, {restored.inserts:,} inserted, "
            f"{restored.samples:,} sampled; updates resume without a refill "
            f"({phases[0].env_steps:,} env steps and "
            f"{phases[0].updates - state.updates:,} updates left)",
            flush=True,
        )
    return phases
