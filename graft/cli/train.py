"""`graft presets` and `graft train`: the presets listed, one run trained and reported."""

from __future__ import annotations

import argparse
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from graft.cli.flags import (
    DEFAULT_PRESET,
    INTERRUPTED,
    TERMINATED,
    UsageError,
    at_least,
    ray_address,
    set_overrides,
)

if TYPE_CHECKING:
    from graft.config import TrainConfig


def add_train_commands(commands: argparse._SubParsersAction) -> None:
    """Adds `graft presets` and `graft train` to the `graft` parser's commands."""
    from graft.config import preset_descriptions

    presets = commands.add_parser("presets", help="list the presets, one line each")
    presets.set_defaults(handler=_presets)

    train = commands.add_parser(
        "train",
        help="train a preset on a Ray cluster",
        epilog="presets:\n" + _preset_table(preset_descriptions()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    train.add_argument(
        "--preset",
        help=f"a preset's name (listed below, `graft presets`) or a path to a YAML file "
        f"(default {DEFAULT_PRESET}; with --resume, the run's own)",
    )
    train.add_argument(
        "--actors",
        "--clients",
        dest="actors",
        type=int,
        help="number of env actors (preset default); Minecraft presets: one simulated world "
        "each, on its actor's node (real clients: --set clients_file=FILE)",
    )
    train.add_argument(
        "--address",
        help="'local' starts a new local Ray instance; 'auto', host:port or ray://host:port "
        "joins one (default: RAY_ADDRESS if set, else local)",
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
    train.add_argument(
        "--run-dir",
        type=Path,
        help="a new (or empty) folder; default runs/<preset>-s<seed>-<time>",
    )
    train.add_argument("--resume", action="store_true", help="continue from --run-dir's checkpoint")
    train.add_argument(
        "--reproducible",
        action="store_true",
        help="lock-step actors and learner: the same seed rewrites the same metrics.csv "
        "(slower; wall-clock metrics go to timing.csv)",
    )
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.set_defaults(handler=_train)


def _presets(args: argparse.Namespace) -> None:
    from graft.config import preset_descriptions

    print(_preset_table(preset_descriptions()))


def _preset_table(descriptions: dict[str, str]) -> str:
    width = max(map(len, descriptions))
    return "\n".join(f"  {name:<{width}}  {text}" for name, text in descriptions.items())


def _train(args: argparse.Namespace) -> None:
    from graft.recipe import recipe_line
    from graft.validation import ConfigError

    at_least("train", "--actors", args.actors, 1)
    at_least("train", "--env-steps", args.env_steps, 1)
    at_least("train", "--seed", args.seed, 0)
    try:
        config = _train_config(args)
    except ConfigError as error:
        raise UsageError("train", str(error)) from None
    line = recipe_line(config.preset, config.recipe)
    if line is not None and not args.resume:
        print(f"graft train: {line}", file=sys.stderr)
    address = ray_address("train", args.address)
    # Imported once the input is checked: torch and Ray take seconds to load, and a refusal
    # above comes without them.
    from graft.api import train
    from learner.checkpoint import latest_checkpoint

    terminated = _stop_on_sigterm()
    try:
        result = train(
            config,
            address=address,
            run_dir=args.run_dir,
            resume=args.resume,
            progress=not args.no_progress,
        )
    except ConfigError as error:
        raise UsageError("train", str(error)) from None
    except KeyboardInterrupt:
        print(
            f"graft train: {'terminated' if terminated else 'interrupted'} while starting, "
            "before any update; no checkpoint written",
            file=sys.stderr,
        )
        raise SystemExit(TERMINATED if terminated else INTERRUPTED) from None
    s = result.summary
    if result.stopped is not None:  # the disk filled: the line says what and where
        print(f"graft train: stopped: {result.stopped}", file=sys.stderr)
        raise SystemExit(1)
    if result.interrupted:
        checkpoint = latest_checkpoint(result.run_dir / "checkpoints")
        print(
            f"graft train: {'terminated' if terminated else 'interrupted'} at "
            f"{s['env_steps']} env steps; checkpoint {checkpoint}, "
            f"summary {result.run_dir / 'summary.json'}",
            file=sys.stderr,
        )
        raise SystemExit(TERMINATED if terminated else INTERRUPTED)
    print(f"\nrun folder: {result.run_dir} ({s['mode']} mode)")
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


def _stop_on_sigterm() -> list[int]:
    """Makes SIGTERM stop `graft train` as Ctrl-C does (final checkpoint, summary, the
    replay server and Ray stopped); the returned list is non-empty once it came. A
    second SIGTERM is ignored while the run saves and stops (SIGKILL still ends it)."""
    received: list[int] = []

    def on_sigterm(signum: int, _frame: object) -> None:
        received.append(signum)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_sigterm)
    return received


def _train_config(args: argparse.Namespace) -> TrainConfig:
    """The preset with the flags' overrides; resuming without --preset, the config the run
    folder recorded (whatever preset or YAML file it came from)."""
    import yaml

    from graft.config import config_from_data, load_preset
    from graft.trained import run_config
    from graft.validation import yaml_error

    overrides = train_overrides(args)
    recorded = args.run_dir is not None and (args.run_dir / "config.yaml").is_file()
    if args.preset is None and args.resume and recorded:
        try:
            return config_from_data(run_config(args.run_dir).to_dict(), **overrides)
        except yaml.YAMLError as error:
            raise yaml_error(str(args.run_dir / "config.yaml"), error) from None
    return load_preset(args.preset or DEFAULT_PRESET, **overrides)


def train_overrides(args: argparse.Namespace) -> dict[str, object]:
    """The flags' overrides and `--set`'s in one dict; a field given both ways is an error."""
    flags = {
        "num_actors": ("--actors", args.actors),
        "seed": ("--seed", args.seed),
        "env_steps": ("--env-steps", args.env_steps),
        "reproducible": ("--reproducible", True if args.reproducible else None),
    }
    settings = set_overrides("train", args.set)
    for key, (flag, value) in flags.items():
        if value is not None and key in settings:
            raise UsageError("train", f"{flag} and --set {key}=... both given; give one")
    return {**{key: value for key, (_, value) in flags.items()}, **settings}
