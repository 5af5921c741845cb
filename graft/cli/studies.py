"""`graft experiment` and `graft tune`: a paper figure over seeds, and a throughput sweep."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from graft.cli.flags import (
    DEFAULT_PRESET,
    INTERRUPTED,
    UsageError,
    at_least,
    ray_address,
    set_overrides,
)


def add_study_commands(commands: argparse._SubParsersAction) -> None:
    """Adds `graft experiment` and `graft tune` to the `graft` parser's commands."""
    from graft.experiments.figures import FIGURES

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


def _experiment(args: argparse.Namespace) -> None:
    import ray

    from graft.experiments.runner import plan_experiment, report, run_experiment
    from graft.orchestration.ray_session import connect_ray
    from graft.validation import ConfigError

    if args.replot:
        csv_path, png_path = report(args.figure, args.out)
        print(f"results: {csv_path}\nfigure: {png_path}")
        return
    at_least("experiment", "--seeds", args.seeds, 1)
    at_least("experiment", "--parallel", args.parallel, 1)
    at_least("experiment", "--env-steps", args.env_steps, 1)
    address = ray_address("experiment", args.address)
    plan = {
        "seeds": args.seeds,
        "out_dir": args.out,
        "parallel": args.parallel,
        "overrides": {"env_steps": args.env_steps, **set_overrides("experiment", args.set)},
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
    from graft.tuning.grid import Costs, parse_grid, plan
    from graft.validation import ConfigError

    for flag, value in (("--warmup", args.warmup), ("--measure", args.measure)):
        if not value > 0:
            raise UsageError("tune", f"{flag}={value} must be > 0 seconds")
    address = ray_address("tune", args.address)
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
            args.preset,
            grid,
            overrides=set_overrides("tune", args.set),
            costs=costs,
            address=address,
        )
    except (ConfigError, ValueError) as error:
        raise UsageError("tune", str(error)) from None
    # Imported once the input is checked: torch and Ray take seconds to load.
    from graft.tuning import report as tune_report
    from graft.tuning.sweep import sweep

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
