"""The `graft` command line: train, eval, replay, minecraft."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Optional

from service.run.figures import FIGURES
from service.run.replay_cli import add_replay_commands

if TYPE_CHECKING:
    from service.run.config import TrainConfig

DEFAULT_PRESET = "pendulum-td3"


def _train(args: argparse.Namespace) -> None:
    from service.run.api import train

    try:
        config = _train_config(args)
    except ValueError as error:
        raise SystemExit(f"graft train: {error}") from None
    result = train(
        config,
        address=args.address,
        run_dir=args.run_dir,
        resume=args.resume,
        progress=not args.no_progress,
    )
    s = result.summary
    print(f"\nrun folder: {result.run_dir}")
    print(
        f"final evaluation return: {s['final_eval_return_mean']:.1f} ± "
        f"{s['final_eval_return_std']:.1f} after {s['env_steps']} env steps, "
        f"{s['updates']} updates, {s['wall_s']} s"
    )
    print(
        f"learner: {s['learner_updates_per_s']} updates/s, "
        f"{100 * s['learner_wait_fraction']:.1f}% of its time waiting on replay"
    )
    print(f"actors adopted weight versions up to {s['actor_last_version']}")
    print(f"learning curve: {result.run_dir / 'learning_curve.png'}")


def _train_config(args: argparse.Namespace) -> TrainConfig:
    """The preset with the flags' overrides; resuming without --preset, the config the run
    folder recorded (whatever preset or YAML file it came from)."""
    from service.run.config import config_from_data, load_preset
    from service.run.trained import run_config

    overrides = _train_overrides(args)
    recorded = args.run_dir is not None and (args.run_dir / "config.yaml").is_file()
    if args.preset is None and args.resume and recorded:
        return config_from_data(run_config(args.run_dir).to_dict(), **overrides)
    return load_preset(args.preset or DEFAULT_PRESET, **overrides)


def _train_overrides(args: argparse.Namespace) -> dict[str, object]:
    """The flags' overrides and `--set`'s in one dict; a field given both ways is an error."""
    flags = {
        "num_actors": ("--actors", args.actors),
        "seed": ("--seed", args.seed),
        "env_steps": ("--env-steps", args.env_steps),
    }
    settings = parse_settings(args.set)
    for key, (flag, value) in flags.items():
        if value is not None and key in settings:
            raise ValueError(f"{flag} and --set {key}=... both given; give one")
    return {**{key: value for key, (_, value) in flags.items()}, **settings}


def parse_settings(pairs: list[str]) -> dict[str, object]:
    """`--set section.field=value` pairs as preset overrides (values parsed as YAML)."""
    import yaml

    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(
                f"--set {pair!r}: expected key=value, e.g. backbone.correction_limit=0.5"
            )
        out[key.strip()] = yaml.safe_load(value)
    return out


_EVAL_FIELDS = ("policy", "env_id", "episodes", "mean", "std")


def _eval(args: argparse.Namespace) -> None:
    import numpy as np

    from service.run.api import evaluate, load_policy
    from service.run.config import load_preset

    try:
        if args.policy in ("hardcoded", "random"):
            # The preset names the task; random actions may go to any environment.
            env = {"env_id": args.env_id} if args.policy == "random" else {}
            task = load_preset(args.preset or DEFAULT_PRESET, seed=args.seed, **env)
            policy = load_policy(args.policy, preset=task)
        else:
            policy = load_policy(args.policy)
    except FileNotFoundError as error:
        raise SystemExit(
            f"graft eval: {error}; --policy takes 'hardcoded', 'random', a run folder or a "
            "checkpoint"
        ) from None
    except ValueError as error:
        raise SystemExit(f"graft eval: {error}") from None
    env_id = policy.env.env_id
    if args.env_id not in (None, env_id):
        what = "was trained on" if args.policy not in ("hardcoded", "random") else "acts in"
        raise SystemExit(f"graft eval: {args.policy} {what} {env_id}, not {args.env_id}")
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


def _experiment(args: argparse.Namespace) -> None:
    import ray

    from service.run.experiments import report, run_experiment
    from service.run.launcher import connect_ray

    if args.replot:
        csv_path, png_path = report(args.figure, args.out)
        print(f"results: {csv_path}\nfigure: {png_path}")
        return
    started = connect_ray(args.address)
    try:
        csv_path, png_path = run_experiment(
            args.figure,
            seeds=args.seeds,
            out_dir=args.out,
            parallel=args.parallel,
            overrides={"env_steps": args.env_steps, **parse_settings(args.set)},
            address=args.address,
            only=args.variant or None,
        )
    except ValueError as error:
        raise SystemExit(f"graft experiment: {error}") from None
    finally:
        if started:
            ray.shutdown()
    print(f"results: {csv_path}\nfigure: {png_path}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="graft", description="Improve hard-coded policies with distributed off-policy RL."
    )
    commands = parser.add_subparsers(dest="command", required=True)

    train = commands.add_parser("train", help="train a preset on a Ray cluster")
    train.add_argument(
        "--preset",
        help=f"a preset name or YAML path (default {DEFAULT_PRESET}; with --resume, the run's)",
    )
    train.add_argument(
        "--actors",
        "--clients",
        dest="actors",
        type=int,
        help="number of env actors (preset default); Minecraft presets: simulated worlds",
    )
    train.add_argument(
        "--address",
        default="local",
        help="'local' starts a Ray instance; 'auto' or ray://host:port joins one",
    )
    train.add_argument("--seed", type=int)
    train.add_argument("--env-steps", type=int, help="override the preset's env-step budget")
    train.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a preset field, e.g. --set backbone.teacher=runs/teacher (repeatable)",
    )
    train.add_argument("--run-dir", type=Path, help="default runs/<preset>-s<seed>-<time>")
    train.add_argument("--resume", action="store_true", help="continue from --run-dir's checkpoint")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.set_defaults(handler=_train)

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

    experiment = commands.add_parser(
        "experiment", help="reproduce a paper figure over seeds (runs in parallel on Ray)"
    )
    experiment.add_argument("figure", choices=sorted(FIGURES))
    experiment.add_argument("--seeds", type=int, default=5)
    experiment.add_argument("--parallel", type=int, default=2, help="runs at a time")
    experiment.add_argument("--env-steps", type=int, help="override every variant's budget")
    experiment.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    experiment.add_argument("--address", default="local")
    experiment.add_argument(
        "--variant", action="append", default=[], help="run only this variant (repeatable)"
    )
    experiment.add_argument("--out", type=Path, default=Path("runs/experiments"))
    experiment.add_argument(
        "--replot", action="store_true", help="redraw figure and summary from results.csv"
    )
    experiment.set_defaults(handler=_experiment)

    add_replay_commands(commands)
    try:
        from actors.minecraft.cli import add_minecraft_commands
    except ImportError:  # the Minecraft simulator is optional at import time
        pass
    else:
        add_minecraft_commands(commands)
    return parser


def main(argv: Optional[list[str]] = None) -> None:
    args = build_parser().parse_args(argv if argv is not None else sys.argv[1:])
    handler = getattr(args, "handler", None) or args.func
    code = handler(args)
    if isinstance(code, int) and code:
        raise SystemExit(code)


if __name__ == "__main__":
    main()
