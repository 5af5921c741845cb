"""The `graft` command line: presets, train, eval, experiment, replay, minecraft.

A bad value is one line on stderr naming the field, the value and what is allowed, and
exit status 2; Ctrl-C during `graft train` exits with status 130 after a final checkpoint."""

from __future__ import annotations

import argparse
import dataclasses
import json
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn, Optional

from service.run.figures import FIGURES
from service.run.replay_cli import add_replay_commands

if TYPE_CHECKING:
    from service.run.config import TrainConfig

DEFAULT_PRESET = "pendulum-td3"

INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), as shells report it."""
TERMINATED = 143
"""Exit status after SIGTERM (128 + SIGTERM), which stops a run as Ctrl-C does."""


class UsageError(SystemExit):
    """A bad command-line value: one line on stderr (main prints it), exit status 2."""

    def __init__(self, command: str, message: str) -> None:
        super().__init__(2)
        self.message = f"graft {command}: {message}"

    def __str__(self) -> str:
        return self.message


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad flag is one line (the command, the flag, what is wrong), not the
    usage block; `--help` still shows everything."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _at_least(command: str, flag: str, value: Optional[int], minimum: int) -> None:
    if value is not None and value < minimum:
        raise UsageError(command, f"{flag}={value} must be >= {minimum}")


def _presets(args: argparse.Namespace) -> None:
    from service.run.config import preset_descriptions

    print(_preset_table(preset_descriptions()))


def _preset_table(descriptions: dict[str, str]) -> str:
    width = max(map(len, descriptions))
    return "\n".join(f"  {name:<{width}}  {text}" for name, text in descriptions.items())


def _address(command: str, given: Optional[str]) -> str:
    """--address, else RAY_ADDRESS (said in one line), else a new local Ray instance."""
    from service.run.launcher import resolve_address

    address, note = resolve_address(given)
    if note:
        print(f"graft {command}: {note}", file=sys.stderr)
    return address


def _train(args: argparse.Namespace) -> None:
    from learner.checkpoint import latest_checkpoint
    from service.run.api import train
    from service.run.validation import ConfigError

    _at_least("train", "--actors", args.actors, 1)
    _at_least("train", "--env-steps", args.env_steps, 1)
    _at_least("train", "--seed", args.seed, 0)
    try:
        config = _train_config(args)
    except ConfigError as error:
        raise UsageError("train", str(error)) from None
    address = _address("train", args.address)
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

    from service.run.config import config_from_data, load_preset
    from service.run.trained import run_config
    from service.run.validation import yaml_error

    overrides = _train_overrides(args)
    recorded = args.run_dir is not None and (args.run_dir / "config.yaml").is_file()
    if args.preset is None and args.resume and recorded:
        try:
            return config_from_data(run_config(args.run_dir).to_dict(), **overrides)
        except yaml.YAMLError as error:
            raise yaml_error(str(args.run_dir / "config.yaml"), error) from None
    return load_preset(args.preset or DEFAULT_PRESET, **overrides)


def _train_overrides(args: argparse.Namespace) -> dict[str, object]:
    """The flags' overrides and `--set`'s in one dict; a field given both ways is an error."""
    flags = {
        "num_actors": ("--actors", args.actors),
        "seed": ("--seed", args.seed),
        "env_steps": ("--env-steps", args.env_steps),
        "reproducible": ("--reproducible", True if args.reproducible else None),
    }
    settings = _settings("train", args.set)
    for key, (flag, value) in flags.items():
        if value is not None and key in settings:
            raise UsageError("train", f"{flag} and --set {key}=... both given; give one")
    return {**{key: value for key, (_, value) in flags.items()}, **settings}


def _settings(command: str, pairs: list[str]) -> dict[str, object]:
    from service.run.validation import ConfigError

    try:
        return parse_settings(pairs)
    except ConfigError as error:
        raise UsageError(command, str(error)) from None


def parse_settings(pairs: list[str]) -> dict[str, object]:
    """`--set section.field=value` pairs as preset overrides (values parsed as YAML).

    Raises:
        ConfigError: a pair without '=' or a value that is not YAML.
    """
    import yaml

    from service.run.validation import ConfigError

    out: dict[str, object] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise ConfigError(
                f"--set {pair!r}: expected key=value, e.g. backbone.correction_limit=0.5"
            )
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as error:
            problem = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise ConfigError(
                f"--set {key.strip()}={value!r}: not a YAML value ({problem})"
            ) from None
    return out


_EVAL_FIELDS = ("policy", "env_id", "episodes", "mean", "std")


def _eval(args: argparse.Namespace) -> None:
    import numpy as np

    from actors.task import add_import_path
    from service.run.api import evaluate, load_policy
    from service.run.config import load_preset
    from service.run.preflight import check_task
    from service.run.validation import ConfigError, check_env_id

    _at_least("eval", "--episodes", args.episodes, 1)
    _at_least("eval", "--seed", args.seed, 0)

    try:
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
            check_task(task, policy=args.policy == "hardcoded")
            policy = load_policy(args.policy, preset=task)
        else:
            policy = load_policy(args.policy)
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

    from service.run.experiments import plan_experiment, report, run_experiment
    from service.run.launcher import connect_ray
    from service.run.validation import ConfigError

    if args.replot:
        csv_path, png_path = report(args.figure, args.out)
        print(f"results: {csv_path}\nfigure: {png_path}")
        return
    _at_least("experiment", "--seeds", args.seeds, 1)
    _at_least("experiment", "--parallel", args.parallel, 1)
    _at_least("experiment", "--env-steps", args.env_steps, 1)
    address = _address("experiment", args.address)
    plan = {
        "seeds": args.seeds,
        "out_dir": args.out,
        "parallel": args.parallel,
        "overrides": {"env_steps": args.env_steps, **_settings("experiment", args.set)},
        "address": address,
        "only": args.variant or None,
    }
    try:
        plan_experiment(args.figure, **plan)  # every variant's config, before Ray starts
    except ConfigError as error:
        raise UsageError("experiment", str(error)) from None
    started = connect_ray(address)
    try:
        csv_path, png_path = run_experiment(args.figure, **plan)
    except KeyboardInterrupt:
        print(
            f"graft experiment: interrupted; the runs finished so far are in "
            f"{args.out / args.figure / 'results.csv'} (`--replot` draws them)",
            file=sys.stderr,
        )
        raise SystemExit(INTERRUPTED) from None
    finally:
        if started:
            ray.shutdown()
    print(f"results: {csv_path}\nfigure: {png_path}")


def _tune(args: argparse.Namespace) -> None:
    from service.run import tune_report
    from service.run.tune import Costs, parse_grid, plan, sweep
    from service.run.validation import ConfigError

    for flag, value in (("--warmup", args.warmup), ("--measure", args.measure)):
        if not value > 0:
            raise UsageError("tune", f"{flag}={value} must be > 0 seconds")
    address = _address("tune", args.address)
    try:
        grid = parse_grid(args.grid)
        costs = Costs(
            learner=args.learner,
            learner_cost_ms=args.learner_cost_ms,
            learner_busy=not args.learner_sleeps,
            step_cost_ms=args.step_cost_ms,
            step_latency_ms=args.step_latency_ms,
            actor_steps_per_s=args.actor_steps_per_s,
            tick_ms=args.tick_ms,
            actor_cpus=args.actor_cpus,
        )
        points = plan(
            args.preset, grid, overrides=_settings("tune", args.set), costs=costs, address=address
        )
    except (ConfigError, ValueError) as error:
        raise UsageError("tune", str(error)) from None
    knobs = list(grid)
    out, done = args.out, []

    def keep(row: dict[str, object]) -> None:  # the CSV grows point by point
        done.append(row)
        tune_report.write_csv(done, out / "tune.csv")

    rows = sweep(
        points, warmup_s=args.warmup, measure_s=args.measure, address=address,
        progress=not args.no_progress, on_row=keep,
    )  # fmt: skip
    tune_report.plot(rows, knobs, out / "tune.png", title=f"graft tune --preset {args.preset}")
    print(tune_report.table(rows, knobs))
    print(tune_report.RULE)
    best = tune_report.recommend(rows, args.objective)
    algorithm = points[0].config.algorithm
    print(
        f"recommended ({args.objective}): "
        + ", ".join(f"{k}={best[k]}" for k in knobs)
        + f" -> {best['inserted_per_s']:.0f} env steps inserted/s, "
        f"{best['learner_updates_per_s']:.1f} updates/s; bottleneck there: {best['bottleneck']}"
    )
    print("preset lines:\n" + "\n".join(tune_report.preset_lines(best, knobs, algorithm)))
    print(f"results: {out / 'tune.csv'}\nfigure: {out / 'tune.png'}")


def build_parser() -> argparse.ArgumentParser:
    from service.run.config import preset_descriptions

    parser = _Parser(
        prog="graft", description="Improve hard-coded policies with distributed off-policy RL."
    )
    commands = parser.add_subparsers(dest="command", required=True)

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
    experiment.add_argument(
        "--address", help="as for train (default: RAY_ADDRESS if set, else local)"
    )
    experiment.add_argument(
        "--variant", action="append", default=[], help="run only this variant (repeatable)"
    )
    experiment.add_argument("--out", type=Path, default=Path("runs/experiments"))
    experiment.add_argument(
        "--replot", action="store_true", help="redraw figure and summary from results.csv"
    )
    experiment.set_defaults(handler=_experiment)

    tune = commands.add_parser(
        "tune",
        help="sweep throughput knobs with simulated actors; name the bottleneck",
        description="Runs the preset's pipeline (replay server, Ray actors stepping simulated "
        "environments with the preset's spaces and behaviour, weight broadcast, learner) at "
        "every point of a grid, each for --measure seconds after --warmup, and names the "
        "component that saturated first. Knobs: actors, envs (per actor), steps_per_insert, "
        "batch_size, samples_per_insert, publish_interval, slack, any preset field, and the "
        "simulated costs (step_cost_ms, step_latency_ms, actor_steps_per_s, tick_ms, "
        "learner_cost_ms, actor_cpus).",
    )
    tune.add_argument("--preset", default=DEFAULT_PRESET, help="a preset's name or YAML path")
    tune.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KNOB=V1,V2",
        help="a knob's values, e.g. --grid actors=1,2,4 (repeatable: the grid is the product)",
    )
    tune.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    tune.add_argument(
        "--learner", choices=("real", "cost", "drain"), default="real",
        help="the preset's algorithm, a fixed cost per update, or drawing batches only",
    )  # fmt: skip
    tune.add_argument("--learner-cost-ms", type=float, default=0.0, help="cost learner: ms/update")
    tune.add_argument("--learner-sleeps", action="store_true", help="cost learner sleeps (no CPU)")
    tune.add_argument("--step-cost-ms", type=float, default=0.0, help="CPU per simulated env step")
    tune.add_argument("--step-latency-ms", type=float, default=0.0, help="sleep per env step")
    tune.add_argument("--actor-steps-per-s", type=float, default=0.0, help="0: as fast as possible")
    tune.add_argument("--tick-ms", type=float, default=0.0, help="real-time worlds' tick (0: off)")
    tune.add_argument("--actor-cpus", type=float, default=0.25, help="CPUs Ray reserves per actor")
    tune.add_argument("--warmup", type=float, default=5.0, help="seconds before measuring")
    tune.add_argument("--measure", type=float, default=10.0, help="seconds measured per point")
    tune.add_argument("--objective", choices=("inserted", "updates"), default="inserted")
    tune.add_argument("--address", help="as for train (default: RAY_ADDRESS if set, else local)")
    tune.add_argument("--out", type=Path, default=Path("runs/tune"))
    tune.add_argument("--no-progress", action="store_true")
    tune.set_defaults(handler=_tune)

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
    try:
        code = handler(args)
    except UsageError as error:
        print(error.message, file=sys.stderr)
        raise
    if isinstance(code, int) and code:
        raise SystemExit(code)


if __name__ == "__main__":
    main()
