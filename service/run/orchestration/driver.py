"""One training run driven from this process (Ray's driver): the replay servers, weight
broadcaster, step budget, env actors and evaluator started, the learner loop run here, and
everything saved and stopped, whatever ends the run.

A reproducible run (`reproducible: true`) has the learner drive the actors in lock-step
instead (`lockstep`). What differs between algorithms comes from the algorithm's builder
(service/run/registry.py); this module knows none of them.
"""

from __future__ import annotations

import dataclasses
import json
import secrets
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
from learner.agent import Phase
from learner.device import device_name
from learner.loop import LearnerLoop, Lockstep, LoopSettings, LoopState
from service.core import Evaluation, SampleStream
from service.metrics import MetricsLogger, plot_learning_curve
from service.run.config import TrainConfig
from service.run.orchestration.budget import StepBudget
from service.run.orchestration.clients import actor_env, evaluator_env, world_clients
from service.run.orchestration.kept import (
    BROADCASTER,
    BUDGET,
    ENV_ACTORS,
    EVALUATOR,
    KEPT,
    env_actor,
    options_key,
    take_or_start,
)
from service.run.orchestration.lockstep import ActorRing, deterministic, stalled
from service.run.orchestration.preflight import check_cluster, check_fits_locally, check_run_dir
from service.run.orchestration.progress import FaultLog, say_and_keep, watch
from service.run.orchestration.provenance import config_record
from service.run.orchestration.ray_session import check_head, connect_ray
from service.run.orchestration.resume import restore, resume_with
from service.run.orchestration.roles import (
    ACTOR_FINISH_S,
    actor_segments,
    learner_device,
    probe,
    start_replay,
)
from service.run.orchestration.summary import REFERENCE_LEVELS, log_behaviour_stats, summarise
from service.run.orchestration.supervision import ActorFleet, Supervisor
from service.run.orchestration.tables import preset_tables
from service.run.replay_host.folder import open_replay, reusable
from service.run.replay_host.shards import RunReplay
from service.run.seeds import evaluation_seed, training_seed
from service.weights import BroadcastPublisher


@dataclass
class RunResult:
    """What a finished (or interrupted) run reports (also written to summary.json)."""

    run_dir: Path
    summary: dict[str, Any]
    evaluations: list[Evaluation]
    interrupted: bool = False
    """Ctrl-C stopped the run; its last checkpoint holds the state at `summary['env_steps']`."""


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
    run_dir, checkpoint = check_run_dir(config, run_dir, resume)
    check_fits_locally(config, address)
    device, compile_mode = learner_device(config)  # a GPU that is not here: refused before Ray
    clients = world_clients(config)
    torch.set_num_threads(1)  # the learner shares 2 cores with actors and the replay server
    start = time.perf_counter()
    builder, behaviour, signature = probe(config)
    algorithm = builder.make_learner(device=device, compile=compile_mode)
    state, phases = LoopState(), builder.phases()
    # A phase's table does not depend on its budget: a resumed run serves the same one.
    tables = preset_tables(config, phases=phases, signature=signature)
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
    started_ray = connect_ray(address)
    actors: Optional[ActorFleet] = None
    replay: Optional[RunReplay] = None
    supervisor: Optional[Supervisor] = None
    publisher: Optional[BroadcastPublisher] = None
    evaluator: Optional[RemoteEvaluator] = None
    interrupted, finished, release_sigint = False, False, _no_op
    restore_torch = deterministic(config.seed) if config.reproducible else _no_op
    try:
        check_cluster(config, address)
        # Beyond one machine the replay server must listen on the network: then it needs
        # a token.
        host = "127.0.0.1" if address == "local" else "0.0.0.0"
        token = None if address == "local" else secrets.token_urlsafe(24)
        replay, restored = open_replay(
            lambda: start_replay(tables, config, host=host, token=token, run_dir=run_dir),
            run_dir=run_dir,
            tables=tables,
            token=token,
            resumed_env_steps=state.env_steps if checkpoint is not None else None,
            reproducible=config.reproducible,
            shards=config.replay.shards,
            say=_print,
        )
        if checkpoint is not None:
            phases = resume_with(phases, state, config, restored, builder.batch_size)
        client = replay.sampler()
        node = ray.get_runtime_context().get_node_id()
        publisher = BroadcastPublisher(kept=KEPT.take(BROADCASTER, node))
        notes: list[str] = []
        say = say_and_keep(notes, progress)
        evaluator_options = config.evaluator.ray_options()
        evaluator_key = options_key(evaluator_options)
        evaluator = RemoteEvaluator(
            env=evaluator_env(config, clients),
            behaviour=builder.make_behaviour(num_actors=1),
            seed=evaluation_seed(config.seed),
            options=evaluator_options,
            max_restarts=config.evaluator.max_restarts,
            on_restart=say,
            kept=KEPT.take(EVALUATOR, evaluator_key),
        )
        resumed_env_steps = state.env_steps  # a restored table's env steps (resume_with)

        actor_options = {**config.actors.ray_options(), "max_concurrency": 2}

        def make_actor(i: int, incarnation: int) -> Any:
            # A dead actor's replacement is a new process, never a kept one.
            arguments = dict(
                env=actor_env(config, clients, i),
                num_envs=config.envs_per_actor,
                # A replacement explores from other seeds than the actor it replaces, and
                # none a run evaluates or a benchmark holds out (`seeds`).
                seed=training_seed(config.seed, i * config.envs_per_actor, incarnation),
                replay=replay.writer(i),
                weights=publisher.subscriber(),
                behaviour=behaviour,
                steps_per_insert=config.steps_per_insert,
                async_envs=config.async_envs,
                nice=config.actor_nice,
            )
            return env_actor(actor_options, arguments, kept=incarnation == 0)

        # Asynchronous: every actor claims the steps of each phase from one shared budget,
        # an insert batch at a time, until the phase's budget is spent (so none idles
        # while others act); a dead one is replaced. Reproducible: each has a fixed share,
        # and the learner asks them for one insert batch at a time (ActorRing) and draws
        # each batch only when it needs it; wall-clock metrics go to timing.csv, not
        # metrics.csv. A dead actor there ends the run (a replacement would change what
        # the seed computes).
        segments = actor_segments(phases, config.num_actors)
        budget = None
        if not config.reproducible and config.num_actors > 1:
            # Shared by the actors (one alone acts its whole share: no process for it).
            # On the learner's node, as the weight broadcaster: a worker node lost with
            # its actors must not take the budget along. @ray.remote gives the class
            # `.options` at run time; mypy sees the plain class.
            here = NodeAffinitySchedulingStrategy(node, False)
            totals = {s.table: s.steps for s in actor_segments(phases, 1)}
            budget = take_or_start(
                BUDGET,
                node,
                lambda: StepBudget.options(scheduling_strategy=here).remote(totals),  # type: ignore[attr-defined]
                lambda kept: kept.reset.remote(totals),
            )
        actors = ActorFleet(
            make_actor,
            segments if budget is None else actor_segments(phases, 1),
            config.num_actors,
            max_restarts=0 if config.reproducible else config.actors.max_restarts,
            start=not config.reproducible,
            budget=budget,
        )
        supervisor = Supervisor(replay, actors, say)
        lockstep = (
            Lockstep(ActorRing(actors.handles, segments), builder.batch_size)
            if config.reproducible
            else None
        )
        logger = MetricsLogger(run_dir, wall_clock=not config.reproducible)
        prefetch = 0 if config.reproducible else config.prefetch

        def open_stream(phase: Phase) -> SampleStream:
            return client.sample_stream(
                phase.name, builder.batch_size, prefetch=prefetch, **_window(phase)
            )

        settings = LoopSettings(
            publish_every=config.publish_every,
            eval_every=config.eval_every,
            eval_episodes=config.eval_episodes,
            checkpoint_every=config.checkpoint_every,
            keep_checkpoints=config.keep_checkpoints,
            selection=config.selection,
        )
        bar = tqdm(
            total=sum(p.updates for p in phases),
            initial=state.updates,
            unit="upd",
            disable=not progress,
            dynamic_ncols=True,
        )

        faults = FaultLog(logger, supervisor, evaluator)

        def on_progress(s: LoopState) -> None:
            supervisor.raise_error()
            if s.updates % 100 == 0:
                faults.log(s)
                bar.update(s.updates - bar.n)
                last = s.evaluations[-1]["mean"] if s.evaluations else float("nan")
                bar.set_postfix(env_steps=s.env_steps, eval_return=f"{last:.0f}", version=s.version)

        loop = LearnerLoop(
            algorithm,
            phases=phases,
            open_stream=open_stream,
            publisher=publisher,
            evaluator=evaluator,
            logger=logger,
            checkpoint_dir=run_dir / "checkpoints",
            settings=settings,
            state=state,
            on_progress=on_progress,
            watchdog=stalled
            if config.reproducible
            else lambda: watch(supervisor, actors, faults, loop.state),
            lockstep=lockstep,
            env_steps_offset=restored.env_steps_before if restored is not None else None,
            device=device,
            prefetch_to_device=config.learner.prefetch_to_device,
        )
        try:
            final = loop.run()
            bar.update(final.updates - bar.n)
            publisher.stop()
            supervisor.stop()
            supervisor.raise_error()
            if config.reproducible:
                finishing = [a.finish.remote() for a in actors.handles]
                actor_reports = ray.get(finishing, timeout=ACTOR_FINISH_S)
            else:
                actor_reports, leftovers = actors.reports(timeout_s=ACTOR_FINISH_S)
                for line in leftovers:
                    say(line)
            # The learner may stop before it sees the actors' last inserts: count them directly.
            final.env_steps = resumed_env_steps + sum(r["env_steps"] for r in actor_reports)
        except KeyboardInterrupt:  # Ctrl-C: stop here and keep what was learned
            interrupted, final, actor_reports = True, loop.state, []
        finally:
            # From here on the run only saves and stops: a (second) Ctrl-C must not cut that
            # short and leave a half-written folder or processes behind.
            release_sigint = _hold_sigint()
            bar.close()
        if interrupted:  # no final selection: the newest in-run evaluation's verdict holds
            loop.keep_guarded()
        loop.checkpoint()  # with the env-step count a resume continues from
        faults.log(final, always=True)
        log_behaviour_stats(logger, actor_reports, config.num_actors, resumed_env_steps)
        logger.close()
        summary = summarise(config, final, actor_reports, time.perf_counter() - start)
        if config.replay.shards > 1:
            summary["replay_shard_inserts"] = replay.inserts()
        summary["interrupted"] = interrupted
        summary["selection"] = final.selection or None
        summary["guard"] = final.guard or None
        summary["replay_restored"] = dataclasses.asdict(restored) if restored else None
        summary["mode"] = "reproducible" if config.reproducible else "asynchronous"
        summary.update(hardware, learner_compile=compile_mode)
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        plot_learning_curve(
            run_dir / "metrics.csv",
            run_dir / "learning_curve.png",
            title=f"{config.preset} (seed {config.seed})",
            reference=REFERENCE_LEVELS.get(config.env_id),
        )
        finished = True
    finally:
        if supervisor is not None:
            supervisor.stop()
        # A run that ended well on a Ray instance that stays hands its helpers on (kept.py).
        keep = finished and not started_ray
        if actors is not None:
            # An interrupted run's actors may still be acting: they are ended, not kept.
            if keep and not interrupted:
                KEPT.keep(ENV_ACTORS, options_key(actor_options), *actors.release())
                if budget is not None:
                    KEPT.keep(BUDGET, node, budget)
            else:
                actors.kill()
        if evaluator is not None:
            if keep:
                KEPT.keep(EVALUATOR, evaluator_key, evaluator.release())
            else:
                evaluator.close()
        if publisher is not None:
            if keep:
                KEPT.keep(BROADCASTER, node, publisher.release())
            else:
                publisher.close()
        if replay is not None:
            replay.stop()
        if started_ray:
            ray.shutdown()
        restore_torch()
        release_sigint()
    return RunResult(run_dir, summary, final.evaluations, interrupted=interrupted)


def _no_op() -> None:
    pass


def _print(line: str) -> None:
    print(line, flush=True)


def _hold_sigint() -> Callable[[], None]:
    """Ignores SIGINT (main thread only) until the returned function is called."""
    if threading.current_thread() is not threading.main_thread():
        return _no_op
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)

    def release() -> None:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.SIG_DFL)

    return release


def _window(phase: Phase) -> dict[str, int]:
    """Sampling arguments for a phase: windows of k steps when it asks for them."""
    return {"sequence_length": phase.sequence_length} if phase.sequence_length > 1 else {}
