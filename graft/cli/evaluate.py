"""`graft eval`: the mean return of a hard-coded, random or trained policy over episodes."""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

from graft.cli.flags import DEFAULT_PRESET, UsageError, at_least


def add_eval_command(commands: argparse._SubParsersAction) -> None:
    """Adds `graft eval` to the `graft` parser's commands."""
    evaluate = commands.add_parser("eval", help="mean return of a policy over episodes")
    evaluate.add_argument(
        "--policy",
        default="hardcoded",
        help="'hardcoded', 'random', or a run folder / checkpoint path",
    )
    evaluate.add_argument(
        "--preset",
        help="the task (name or YAML path) of 'hardcoded' and 'random' (default pendulum-td3)",
    )
    evaluate.add_argument("--env-id", help="default: the run's or the preset's environment")
    evaluate.add_argument("--episodes", type=int, default=100)
    evaluate.add_argument("--seed", type=int, default=0)
    evaluate.add_argument("--json", action="store_true")
    evaluate.set_defaults(handler=_eval)


_EVAL_FIELDS = ("policy", "env_id", "episodes", "mean", "std")


def _eval(args: argparse.Namespace) -> None:
    from actors.task import add_import_path
    from graft.config import load_preset
    from graft.validation import ConfigError, check_env_id
    from learner.checkpoint import find_checkpoint

    at_least("eval", "--episodes", args.episodes, 1)
    at_least("eval", "--seed", args.seed, 0)

    try:
        # The preset, the environment id and the policy's path are checked before torch
        # and Ray (seconds to import) load.
        task = None
        if args.policy in ("hardcoded", "random"):
            task = load_preset(args.preset or DEFAULT_PRESET, seed=args.seed)
            if args.env_id is not None:
                add_import_path(task.import_path)
                try:
                    check_env_id(args.env_id)
                except ConfigError as error:
                    raise UsageError("eval", f"--env-id: {error}") from None
                if args.policy == "random":  # random actions may go to any environment
                    task = dataclasses.replace(task, env_id=args.env_id)
        else:
            find_checkpoint(Path(args.policy))
        from graft.api import load_policy
        from graft.orchestration.preflight import check_task

        if task is None:
            policy = load_policy(args.policy)
        else:
            check_task(task, policy=args.policy == "hardcoded")
            policy = load_policy(args.policy, preset=task)
    except FileNotFoundError as error:
        raise UsageError(
            "eval",
            f"{error}; --policy takes 'hardcoded', 'random', a run folder or a checkpoint",
        ) from None
    except ValueError as error:  # a ConfigError, or the task's refusal (one line)
        raise UsageError("eval", str(error).splitlines()[0]) from None
    env_id = policy.env.env_id
    if args.env_id not in (None, env_id):
        what = "was trained on" if args.policy not in ("hardcoded", "random") else "acts in"
        raise UsageError("eval", f"{args.policy} {what} {env_id}, not {args.env_id}")
    import numpy as np

    from graft.api import evaluate

    result = evaluate(policy, episodes=args.episodes, seed=args.seed)
    out = {
        "policy": args.policy,
        "env_id": env_id,
        "episodes": args.episodes,
        "mean": result.mean,
        "std": result.std,
        **{name: float(np.nanmean(v)) for name, v in result.metrics.items()},
    }
    print(
        json.dumps(out)
        if args.json
        else f"{args.policy} on {env_id}: mean return {out['mean']:.1f} ± "
        f"{out['std']:.1f} over {args.episodes} episodes"
        + "".join(f"; {k} {v:.3g}" for k, v in out.items() if k not in _EVAL_FIELDS)
    )
