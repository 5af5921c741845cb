"""Orchestration of one training run: Ray, the replay server, actors, evaluator and learner.

    graft train --preset pendulum-td3
      ├─ replay server      (child process, gRPC on loopback)
      ├─ weight broadcaster (Ray actor)
      ├─ N env actors       (Ray actors) ──insert──▶ replay
      ├─ evaluator          (Ray actor)
      └─ learner loop       (this process) ◀──sample── replay, ──publish──▶ broadcaster
"""

from __future__ import annotations

import json
import secrets
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import gymnasium as gym
import ray
import torch
import yaml
from tqdm import tqdm

from actors.env_actor import EnvActor
from actors.evaluator import Evaluator
from actors.transitions import transition_signature
from learner.checkpoint import latest_checkpoint, load_checkpoint
from learner.loop import LearnerLoop, LoopSettings, LoopState
from learner.td3.builder import make_td3_learner
from service.client import ReplayClient
from service.config import TrainConfig
from service.metrics import MetricsLogger, plot_learning_curve
from service.replay_process import ReplayProcess
from service.weights import WeightBroadcaster

TABLE = "transitions"
# Reference levels drawn on learning curves (measured with `graft eval`, 100 episodes).
REFERENCE_LEVELS = {"Pendulum-v1": {"hard-coded policy": -429.0}}


def transition_table_spec(config: TrainConfig) -> dict[str, Any]:
    """The replay table a preset trains from, with the rate limiter holding its update ratio."""
    env = gym.make(config.env_id)
    samples_per_insert = config.updates_per_env_step * config.td3.batch_size
    return {
        "name": TABLE,
        "max_size": config.replay_max_size,
        "signature": transition_signature(env.observation_space, env.action_space),
        "rate_limiter": {
            "kind": "sample_to_insert_ratio",
            "samples_per_insert": samples_per_insert,
            "min_size": config.learning_starts,
            "error_buffer": config.slack_env_steps * samples_per_insert,
        },
    }


def connect_ray(address: str) -> bool:
    """Starts a local Ray instance ('local') or joins a cluster; True if we started it."""
    if ray.is_initialized():
        return False
    if address == "local":
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
        return True
    ray.init(address=address, log_to_driver=False)
    return False


def default_run_dir(config: TrainConfig) -> Path:
    return Path("runs") / f"{config.preset}-s{config.seed}-{time.strftime('%Y%m%d-%H%M%S')}"


@dataclass
class RunResult:
    """What a finished run reports (also written to summary.json)."""

    run_dir: Path
    summary: dict[str, Any]
    evaluations: list[dict[str, Any]]


def train(
    config: TrainConfig,
    *,
    address: str = "local",
    run_dir: Optional[Path] = None,
    resume: bool = False,
    progress: bool = True,
) -> RunResult:
    """Runs one preset end to end and writes the run folder."""
    run_dir = Path(run_dir) if run_dir else default_run_dir(config)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))
    torch.set_num_threads(1)  # the learner shares 2 cores with actors and the replay server
    started_ray = connect_ray(address)
    # Beyond one machine the replay server must listen on the network: then it needs a token.
    host = "127.0.0.1" if address == "local" else "0.0.0.0"
    token = None if address == "local" else secrets.token_urlsafe(24)
    start = time.perf_counter()
    replay = ReplayProcess(
        [transition_table_spec(config)], host=host, token=token, log_path=run_dir / "replay.log"
    )
    actors: list[Any] = []
    try:
        connect_to = replay.address
        if host == "0.0.0.0":
            connect_to = f"{ray.util.get_node_ip_address()}:{replay.address.rsplit(':', 1)[1]}"
        client = ReplayClient(connect_to, token=token)
        env = gym.make(config.env_id)
        algorithm = make_td3_learner(env.observation_space, env.action_space, config.td3, config.seed)
        state = LoopState()
        if resume and (found := latest_checkpoint(run_dir / "checkpoints")):
            saved = load_checkpoint(found)
            algorithm.load_state_dict(saved["algorithm"])
            state = LoopState(**saved["loop"])
            print(f"resumed from {found} at {state.updates} updates, {state.env_steps} env steps")
        broadcaster = WeightBroadcaster.remote()
        evaluator = Evaluator.remote(env_id=config.env_id, td3=config.td3, seed=10_000 + config.seed)
        resumed_env_steps = state.env_steps
        remaining = config.env_steps - state.env_steps
        total_updates = config.total_updates
        if state.updates:
            # Replay contents are not in the learner checkpoint: the new table refills to
            # learning_starts with the restored policy before updates resume.
            if remaining <= config.learning_starts:
                raise ValueError(
                    f"nothing left to train: the checkpoint is at {state.env_steps} env steps, "
                    f"the budget is {config.env_steps} and refilling replay takes "
                    f"{config.learning_starts}; raise --env-steps"
                )
            total_updates = state.updates + int(
                (remaining - config.learning_starts) * config.updates_per_env_step
            )
        per_actor = -(-remaining // config.num_actors)
        random_per_actor = 0 if state.updates else -(-config.learning_starts // config.num_actors)
        for i in range(config.num_actors):
            actor = EnvActor.remote(
                env_id=config.env_id,
                num_envs=config.envs_per_actor,
                seed=config.seed * 1000 + i * config.envs_per_actor,
                replay=client,
                table=TABLE,
                broadcaster=broadcaster,
                td3=config.td3,
                steps_per_insert=config.steps_per_insert,
            )
            actors.append(actor)
        runs = [a.run.remote(per_actor, random_per_actor) for a in actors]
        logger = MetricsLogger(run_dir)
        stream = client.sample_stream(TABLE, config.td3.batch_size, prefetch=config.prefetch)
        settings = LoopSettings(
            total_updates=total_updates,
            publish_every=config.publish_every,
            eval_every=config.eval_every,
            eval_episodes=config.eval_episodes,
            checkpoint_every=config.checkpoint_every,
        )
        with tqdm(total=settings.total_updates, initial=state.updates, unit="upd",
                  disable=not progress, dynamic_ncols=True) as bar:

            def on_progress(s: LoopState) -> None:
                if s.updates % 100 == 0:
                    bar.update(s.updates - bar.n)
                    last = s.evaluations[-1]["mean"] if s.evaluations else float("nan")
                    bar.set_postfix(env_steps=s.env_steps, eval_return=f"{last:.0f}",
                                    version=s.version)

            loop = LearnerLoop(algorithm, stream=stream, broadcaster=broadcaster,
                               evaluator=evaluator, logger=logger,
                               checkpoint_dir=run_dir / "checkpoints", settings=settings,
                               state=state, on_progress=on_progress)
            final = loop.run()
            bar.update(final.updates - bar.n)
        stream.close()
        ray.get(broadcaster.stop.remote())
        actor_reports = ray.get(runs, timeout=120)
        # The learner may stop before it sees the actors' last inserts: count them directly.
        final.env_steps = resumed_env_steps + sum(r["env_steps"] for r in actor_reports)
        logger.close()
    finally:
        for actor in actors:
            ray.kill(actor)
        replay.stop()
        if started_ray:
            ray.shutdown()
    wall = time.perf_counter() - start
    summary = _summarise(config, final, actor_reports, wall)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
    plot_learning_curve(run_dir / "metrics.csv", run_dir / "learning_curve.png",
                        title=f"{config.preset} (seed {config.seed})",
                        reference=REFERENCE_LEVELS.get(config.env_id))
    return RunResult(run_dir, summary, final.evaluations)


def _summarise(config: TrainConfig, s: LoopState, reports: list[dict[str, Any]],
               wall: float) -> dict[str, Any]:
    final_eval = s.evaluations[-1] if s.evaluations else {"mean": float("nan"), "std": float("nan")}
    busy = s.wait_s + s.update_s
    return {
        "preset": config.preset,
        "seed": config.seed,
        "env_steps": s.env_steps,
        "updates": s.updates,
        "policy_version": s.version,
        "wall_s": round(wall, 1),
        "final_eval_return_mean": final_eval["mean"],
        "final_eval_return_std": final_eval["std"],
        "learner_updates_per_s": round(s.updates / max(s.update_s + s.wait_s, 1e-9), 1),
        "learner_wait_fraction": round(s.wait_s / max(busy, 1e-9), 4),
        "actor_env_steps": [r["env_steps"] for r in reports],
        "actor_versions_adopted": [len(r["versions_seen"]) for r in reports],
        "actor_last_version": [max(r["versions_seen"], default=-1) for r in reports],
    }
