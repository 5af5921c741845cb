"""One training run driven from this process (Ray's driver): the replay servers, weight
broadcaster, step budget, env actors and evaluator started, the learner loop run here, and
everything saved and stopped, whatever ends the run.

A reproducible run (`reproducible: true`) has the learner drive the actors in lock-step
instead (`lockstep`). What differs between algorithms comes from the algorithm's builder
(graft/registry.py); this module knows none of them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import ray
import torch
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
from tqdm import tqdm

from actors.evaluator import RemoteEvaluator
from graft.config import TrainConfig
from graft.orchestration.assembly import RunParts
from graft.orchestration.budget import StepBudget
from graft.orchestration.checks import check_run
from graft.orchestration.clients import actor_env, evaluator_env
from graft.orchestration.kept import (
    BUDGET,
    env_actor,
    options_key,
    take_or_start,
)
from graft.orchestration.lockstep import ActorRing, deterministic, stalled
from graft.orchestration.preflight import check_cluster, check_run_dir
from graft.orchestration.progress import FaultLog, say_and_keep, watch
from graft.orchestration.provenance import config_record
from graft.orchestration.ray_session import check_head
from graft.orchestration.resume import restore, resume_with
from graft.orchestration.roles import (
    ACTOR_FINISH_S,
    actor_segments,
    start_replay,
)
from graft.orchestration.summary import REFERENCE_LEVELS, log_behaviour_stats, summarise
from graft.orchestration.supervision import ActorFleet, Supervisor
from graft.replay_host.folder import Restored, open_replay, reusable
from graft.replay_host.shards import RunReplay
from graft.seeds import evaluation_seed, training_seed
from learner.agent import Phase
from learner.checkpoint import (
    DiskFull,
    disk_full,
    latest_checkpoint,
    remove_stale_temporaries,
    write_atomically,
)
from learner.device import device_name
from learner.loop import LearnerLoop, Lockstep, LoopSettings, LoopState
from service.core import Evaluation, SampleStream
from service.memory import gib
from service.metrics import MetricsLogger, plot_learning_curve
from service.weights import BroadcastPublisher


@dataclass
class RunResult:
    """What a finished (or interrupted) run reports (also written to summary.json)."""

    run_dir: Path
    summary: dict[str, Any]
    evaluations: list[Evaluation]
    interrupted: bool = False
    """Ctrl-C stopped the run; its last checkpoint holds the state at `summary['env_steps']`."""
    stopped: Optional[str] = None
    """Why the run stopped before its budget, in one line (e.g. the disk filled); None when
    it finished or was interrupted."""


def train_here(
    config: TrainConfig,
    *,
    address: str = "local",
    run_dir: Optional[Path] = None,
    resume: bool = False,
    progress: bool = True,
) -> RunResult:
    """Runs one preset end to end from this process, joined to Ray at `address` ('local',
    'auto' or host:port), and writes the run folder.

    Every value a run cannot use is refused (ConfigError) before anything is written or
    started. Ctrl-C (KeyboardInterrupt) stops the run cleanly: a final checkpoint,
    summary.json with ``interrupted: true``, no process left behind.

    Raises:
        ConfigError: a bad value, a refused run folder or resume, in one line.
    """
    plan = _plan(config, address, run_dir, resume)
    with RunParts(address) as parts:
        sigint = _SigintHold()
        parts.on_exit(sigint.release)  # last: nothing cuts the teardown short
        if config.reproducible:
            parts.on_exit(deterministic(config.seed))
        parts.connect()
        check_cluster(config, address)
        run = _start(parts, config, plan, progress)
        loop, bar, faults = _learner_loop(config, plan, run, progress)
        try:
            final, reports, interrupted, full = _learn(loop, run, config, bar)
        finally:
            # From here on the run only saves and stops: a (second) Ctrl-C must not cut that
            # short and leave a half-written folder or processes behind.
            sigint.hold()
            bar.close()
        if full is not None:  # the disk filled: its parts are ended, not handed on
            summary = _stop_on_full_disk(full, config, plan, final, loop.logger)
            return RunResult(plan.run_dir, summary, final.evaluations, stopped=summary["stopped"])
        summary = _finish(config, plan, run, (loop, faults), final, reports, interrupted)
        parts.keep = True
        parts.keep_actors = not interrupted  # its actors may still be acting: they are ended
    return RunResult(plan.run_dir, summary, final.evaluations, interrupted=interrupted)


@dataclass
class _Plan:
    """What a run was checked and set up with before any process starts."""

    run_dir: Path
    checkpoint: Optional[Path]
    device: torch.device
    compile_mode: str
    clients: Any
    builder: Any
    behaviour: Any
    algorithm: Any
    state: LoopState
    phases: list[Phase]
    tables: Any
    hardware: dict[str, str]
    start: float


def _plan(config: TrainConfig, address: str, run_dir: Optional[Path], resume: bool) -> _Plan:
    """Checks everything that can be checked before Ray starts, builds the algorithm
    (restored from the checkpoint a resume continues from) and writes config.yaml."""
    run_dir, checkpoint = check_run_dir(config, run_dir, resume)
    for stale in remove_stale_temporaries(run_dir / "checkpoints"):
        print(f"removed {stale}, left half-written by a run that stopped mid-write")
    torch.set_num_threads(1)  # the learner shares 2 cores with actors and the replay server
    start = time.perf_counter()
    checked = check_run(config, address)
    device, compile_mode, clients = checked.device, checked.compile_mode, checked.clients
    builder, behaviour, phases = checked.builder, checked.behaviour, checked.phases
    tables, state = checked.tables, LoopState()
    algorithm = builder.make_learner(device=device, compile=compile_mode)
    if checkpoint is not None:
        refill = config.reproducible or not reusable(run_dir, tables)
        state = restore(algorithm, checkpoint, phases, config, refill=refill)
    check_head(address)
    run_dir.mkdir(parents=True, exist_ok=True)
    hardware = {"learner_device": str(device), "learner_device_name": device_name(device)}
    (run_dir / "config.yaml").write_text(config_record(config, hardware=hardware))
    if checkpoint is not None:
        print(f"resumed from {checkpoint} at {state.updates} updates, {state.env_steps} env steps")
    if config.learner.device == "auto":  # said once every check passed; stdout stays clean
        print(f"learner.device=auto picked {device} ({device_name(device)})", file=sys.stderr)
    return _Plan(
        run_dir, checkpoint, device, compile_mode, clients, builder, behaviour, algorithm,
        state, phases, tables, hardware, start,
    )  # fmt: skip


@dataclass
class _Started:
    """A run's parts once started (each registered with the run's `RunParts`)."""

    replay: RunReplay
    restored: Optional[Restored]
    phases: list[Phase]
    publisher: BroadcastPublisher
    evaluator: RemoteEvaluator
    actors: ActorFleet
    supervisor: Supervisor
    segments: Any
    say: Callable[[str], None]
    resumed_env_steps: int
    """The env steps the run starts from (a restored table's: `resume_with`)."""


def _start(parts: RunParts, config: TrainConfig, plan: _Plan, progress: bool) -> _Started:
    """Starts the replay server(s), the weight broadcaster, the evaluator, the step budget
    and the env actors, in that order, each registered with `parts` for the teardown."""
    resumed = plan.checkpoint is not None
    replay, restored = parts.replay(
        lambda: open_replay(
            lambda: start_replay(
                plan.tables, config, host=parts.host, token=parts.token, run_dir=plan.run_dir
            ),
            run_dir=plan.run_dir,
            tables=plan.tables,
            token=parts.token,
            resumed_env_steps=plan.state.env_steps if resumed else None,
            reproducible=config.reproducible,
            shards=config.replay.shards,
            say=_print,
        ),
        stop=lambda opened: opened[0].stop(),
    )
    phases = plan.phases
    if resumed:
        phases = resume_with(phases, plan.state, config, restored, plan.builder.batch_size)
    publisher = parts.broadcaster()
    say = say_and_keep([], progress)
    evaluator_options = config.evaluator.ray_options()
    evaluator = parts.evaluator(
        lambda kept: RemoteEvaluator(
            env=evaluator_env(config, plan.clients),
            behaviour=plan.builder.make_behaviour(num_actors=1),
            seed=evaluation_seed(config.seed),
            options=evaluator_options,
            max_restarts=config.evaluator.max_restarts,
            on_restart=say,
            kept=kept,
        ),
        options_key(evaluator_options),
    )
    actor_options = {**config.actors.ray_options(), "max_concurrency": 2}

    def make_actor(i: int, incarnation: int) -> Any:
        # A dead actor's replacement is a new process, never a kept one.
        arguments = dict(
            env=actor_env(config, plan.clients, i),
            num_envs=config.envs_per_actor,
            # A replacement explores from other seeds than the actor it replaces, and
            # none a run evaluates or a benchmark holds out (`graft.seeds`).
            seed=training_seed(config.seed, i * config.envs_per_actor, incarnation),
            replay=replay.writer(i),
            weights=publisher.subscriber(),
            behaviour=plan.behaviour,
            steps_per_insert=config.steps_per_insert,
            async_envs=config.async_envs,
            nice=config.actor_nice,
        )
        return env_actor(actor_options, arguments, kept=incarnation == 0)

    segments = actor_segments(phases, config.num_actors)
    budget = _step_budget(config, phases, parts.node)
    fleet = ActorFleet(
        make_actor,
        segments if budget is None else actor_segments(phases, 1),
        config.num_actors,
        max_restarts=0 if config.reproducible else config.actors.max_restarts,
        start=not config.reproducible,
        budget=budget,
    )
    actors = parts.actors(fleet, options_key(actor_options), budget)
    supervisor = Supervisor(replay, actors, say)
    parts.on_exit(supervisor.stop)
    return _Started(
        replay, restored, phases, publisher, evaluator, actors, supervisor, segments, say,
        resumed_env_steps=plan.state.env_steps,
    )  # fmt: skip


def _step_budget(config: TrainConfig, phases: list[Phase], node: str) -> Optional[Any]:
    """The step budget the actors share, or None.

    Asynchronous: every actor claims the steps of each phase from one shared budget, an
    insert batch at a time, until the phase's budget is spent (so none idles while others
    act); a dead one is replaced. One actor alone acts its whole share: no process for it.
    Reproducible: each has a fixed share, and the learner asks them for one insert batch at
    a time (ActorRing) and draws each batch only when it needs it; wall-clock metrics go to
    timing.csv, not metrics.csv. A dead actor there ends the run (a replacement would change
    what the seed computes).
    """
    if config.reproducible or config.num_actors == 1:
        return None
    # On the learner's node, as the weight broadcaster: a worker node lost with its actors
    # must not take the budget along. @ray.remote gives the class `.options` at run time;
    # mypy sees the plain class.
    here = NodeAffinitySchedulingStrategy(node, False)
    totals = {s.table: s.steps for s in actor_segments(phases, 1)}
    return take_or_start(
        BUDGET,
        node,
        lambda: StepBudget.options(scheduling_strategy=here).remote(totals),  # type: ignore[attr-defined]
        lambda kept: kept.reset.remote(totals),
    )


def _learner_loop(
    config: TrainConfig, plan: _Plan, run: _Started, progress: bool
) -> tuple[LearnerLoop, tqdm, FaultLog]:
    """The learner loop over the run's phases, its progress bar and its fault log."""
    client = run.replay.sampler()
    batch_size = plan.builder.batch_size
    prefetch = 0 if config.reproducible else config.prefetch
    lockstep = (
        Lockstep(ActorRing(run.actors.handles, run.segments), batch_size)
        if config.reproducible
        else None
    )
    logger = MetricsLogger(plan.run_dir, wall_clock=not config.reproducible)

    def open_stream(phase: Phase) -> SampleStream:
        return client.sample_stream(phase.name, batch_size, prefetch=prefetch, **_window(phase))

    bar = tqdm(
        total=sum(p.updates for p in run.phases),
        initial=plan.state.updates,
        unit="upd",
        disable=not progress,
        dynamic_ncols=True,
    )
    faults = FaultLog(logger, run.supervisor, run.evaluator)

    def on_progress(s: LoopState) -> None:
        run.supervisor.raise_error()
        if s.updates % 100 == 0:
            faults.log(s)
            bar.update(s.updates - bar.n)
            last = s.evaluations[-1]["mean"] if s.evaluations else float("nan")
            bar.set_postfix(env_steps=s.env_steps, eval_return=f"{last:.0f}", version=s.version)

    loop = LearnerLoop(
        plan.algorithm,
        phases=run.phases,
        open_stream=open_stream,
        publisher=run.publisher,
        evaluator=run.evaluator,
        logger=logger,
        checkpoint_dir=plan.run_dir / "checkpoints",
        settings=LoopSettings(
            publish_every=config.publish_every,
            eval_every=config.eval_every,
            eval_episodes=config.eval_episodes,
            checkpoint_every=config.checkpoint_every,
            keep_checkpoints=config.keep_checkpoints,
            selection=config.selection,
        ),
        state=plan.state,
        on_progress=on_progress,
        watchdog=stalled
        if config.reproducible
        else lambda: watch(run.supervisor, run.actors, faults, loop.state),
        lockstep=lockstep,
        env_steps_offset=run.restored.env_steps_before if run.restored is not None else None,
        device=plan.device,
        prefetch_to_device=config.learner.prefetch_to_device,
    )
    return loop, bar, faults


def _learn(
    loop: LearnerLoop, run: _Started, config: TrainConfig, bar: tqdm
) -> tuple[LoopState, list[dict[str, Any]], bool, Optional[DiskFull]]:
    """Runs the loop to its end (or to Ctrl-C, or to a full disk); the final state, the
    actors' reports, whether the run was interrupted and the disk-full error that stopped
    it."""
    try:
        final = loop.run()
        bar.update(final.updates - bar.n)
        run.publisher.stop()
        run.supervisor.stop()
        run.supervisor.raise_error()
        if config.reproducible:
            finishing = [a.finish.remote() for a in run.actors.handles]
            reports = ray.get(finishing, timeout=ACTOR_FINISH_S)
        else:
            reports, leftovers = run.actors.reports(timeout_s=ACTOR_FINISH_S)
            for line in leftovers:
                run.say(line)
    except KeyboardInterrupt:  # Ctrl-C: stop here and keep what was learned
        return loop.state, [], True, None
    except OSError as error:  # a full disk stops the run; the last checkpoint stands
        full = disk_full(error, loop.checkpoint_dir)
        if full is None:
            raise
        return loop.state, [], False, full
    # The learner may stop before it sees the actors' last inserts: count them directly.
    final.env_steps = run.resumed_env_steps + sum(r["env_steps"] for r in reports)
    return final, reports, False, None


def _finish(
    config: TrainConfig,
    plan: _Plan,
    run: _Started,
    learning: tuple[LearnerLoop, FaultLog],
    final: LoopState,
    reports: list[dict[str, Any]],
    interrupted: bool,
) -> dict[str, Any]:
    """Saves what the run learned: the final checkpoint, metrics, summary.json and the
    learning curve; returns the summary."""
    loop, faults = learning
    if interrupted:  # no final selection: the newest in-run evaluation's verdict holds
        loop.keep_guarded()
    loop.checkpoint()  # with the env-step count a resume continues from
    faults.log(final, always=True)
    log_behaviour_stats(loop.logger, reports, config.num_actors, run.resumed_env_steps)
    loop.logger.close()
    summary = summarise(config, final, reports, time.perf_counter() - plan.start)
    if config.replay.shards > 1:
        summary["replay_shard_inserts"] = run.replay.inserts()
    summary["interrupted"] = interrupted
    summary["selection"] = final.selection or None
    summary["guard"] = final.guard or None
    summary["replay_restored"] = dataclasses.asdict(run.restored) if run.restored else None
    summary["mode"] = "reproducible" if config.reproducible else "asynchronous"
    summary.update(plan.hardware, learner_compile=plan.compile_mode)
    write_atomically(plan.run_dir / "summary.json", json.dumps(summary, indent=2))
    plot_learning_curve(
        plan.run_dir / "metrics.csv",
        plan.run_dir / "learning_curve.png",
        title=f"{config.preset} (seed {config.seed})",
        reference=REFERENCE_LEVELS.get(config.env_id),
    )
    return summary


def _stop_on_full_disk(
    full: DiskFull, config: TrainConfig, plan: _Plan, final: LoopState, logger: MetricsLogger
) -> dict[str, Any]:
    """A run the disk stopped: its summary (written where it fits) says so in one line,
    naming the file, the space left, the env steps reached and the last good checkpoint;
    no temporary file is left behind."""
    with contextlib.suppress(OSError):  # its buffered rows may not fit either
        logger.close()
    checkpoints = plan.run_dir / "checkpoints"
    remove_stale_temporaries(checkpoints)
    last = latest_checkpoint(checkpoints)
    summary = summarise(config, final, [], time.perf_counter() - plan.start)
    summary["stopped"] = (
        f"disk full writing {full.path} ({gib(full.free)} free) at {final.env_steps} env "
        f"steps; the last good checkpoint is {last or 'none (none was written)'}"
    )
    summary["interrupted"] = False
    summary["last_checkpoint"] = str(last) if last else None
    with contextlib.suppress(OSError):
        write_atomically(plan.run_dir / "summary.json", json.dumps(summary, indent=2))
    return summary


def _print(line: str) -> None:
    print(line, flush=True)


class _SigintHold:
    """Ignores SIGINT (main thread only) from `hold` until `release`."""

    def __init__(self) -> None:
        self._previous: Optional[Any] = None
        self._held = False

    def hold(self) -> None:
        if threading.current_thread() is threading.main_thread():
            self._previous, self._held = signal.signal(signal.SIGINT, signal.SIG_IGN), True

    def release(self) -> None:
        if self._held:
            previous = self._previous
            signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)
            self._held = False


def _window(phase: Phase) -> dict[str, int]:
    """Sampling arguments for a phase: windows of k steps when it asks for them."""
    return {"sequence_length": phase.sequence_length} if phase.sequence_length > 1 else {}
