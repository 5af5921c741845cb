"""Orchestration of one training run: Ray, the replay server, actors, evaluator and learner.

graft train --preset pendulum-td3
  ├─ replay server      (child process, gRPC on loopback; one table per phase;
  │                      `replay.shards` of them: graft/replay_host/shards.py)
  ├─ weight broadcaster (Ray actor behind the learner's BroadcastPublisher)
  ├─ step budget        (Ray actor: each phase's env steps, claimed by the actors)
  ├─ N env actors       (Ray actors, the algorithm's behaviour) ──insert──▶ replay
  ├─ evaluator          (Ray actor, the behaviour's greedy policy)
  └─ learner loop       (this process) ◀──sample── replay, ──publish──▶ broadcaster

`train` drives the run from this process (`driver.train_here`), or, given a Ray Client
address (``ray://``), from a Ray task inside that cluster (`on_cluster`), which drives it
there the same way.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from graft.config import TrainConfig
from graft.orchestration.driver import RunResult, train_here
from graft.orchestration.on_cluster import train_on_cluster

__all__ = ["RunResult", "train"]


def train(
    config: TrainConfig,
    *,
    address: str = "local",
    run_dir: Optional[Path] = None,
    resume: bool = False,
    progress: bool = True,
) -> RunResult:
    """Runs one preset end to end and writes the run folder.

    Every value a run cannot use is refused (ConfigError) before anything is written or
    started. Ctrl-C (KeyboardInterrupt) stops the run cleanly: a final checkpoint,
    summary.json with ``interrupted: true``, no process left behind.

    Args:
        config: the run's preset with its overrides.
        address: 'local' starts a new local Ray instance; 'auto' or host:port joins a
            cluster from this process; ray://host:port runs the whole run inside that
            cluster.
        run_dir: a new (or empty) folder; None: runs/<preset>-s<seed>-<time>.
        resume: continue from `run_dir`'s last checkpoint.
        progress: draw a progress bar.

    Raises:
        ConfigError: a bad value, a refused run folder or resume, in one line.
    """
    if address.startswith("ray://"):  # outside the cluster: the run goes into it
        return train_on_cluster(config, address=address, run_dir=run_dir, resume=resume)
    return train_here(config, address=address, run_dir=run_dir, resume=resume, progress=progress)
