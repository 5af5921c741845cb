"""What a finished run reports: summary.json's figures and the actors' behaviour scalars
placed at the run's env steps."""

from __future__ import annotations

from typing import Any

from graft.config import TrainConfig
from graft.seeds import evaluation_seed
from learner.loop import LoopState
from service.metrics import MetricsLogger

# Reference levels drawn on learning curves (measured with `graft eval`, 100 episodes).
REFERENCE_LEVELS = {"Pendulum-v1": {"hard-coded policy": -429.0}}


def log_behaviour_stats(
    logger: MetricsLogger, reports: list[dict[str, Any]], num_actors: int, offset: int
) -> None:
    """Actor-side behaviour scalars (ε, option usage), placed at the run's env steps: where
    the shared budget stood (`run_steps`), else the actor's own steps times the actors
    (fixed, equal shares)."""
    for report in reports:
        for row in report.get("behaviour_stats", []):
            steps = offset + row.get("run_steps", row["actor_steps"] * num_actors)
            scalars = {k: v for k, v in row.items() if k not in ("actor_steps", "run_steps")}
            logger.log(
                {f"behaviour/{k}": v for k, v in scalars.items()}, env_steps=steps, updates=0
            )


def summarise(
    config: TrainConfig, s: LoopState, reports: list[dict[str, Any]], wall: float
) -> dict[str, Any]:
    final_eval = s.evaluations[-1] if s.evaluations else {"mean": float("nan"), "std": float("nan")}
    busy = s.wait_s + s.update_s
    return {
        "preset": config.preset,
        "seed": config.seed,
        "evaluation_seed": evaluation_seed(config.seed),  # in-run evaluations, selection
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
