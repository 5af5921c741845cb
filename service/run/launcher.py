"""Orchestration of one training run: Ray, the replay server, actors, evaluator and learner.

graft train --preset pendulum-td3
  ├─ replay server      (child process, gRPC on loopback; one table per phase;
  │                      `replay.shards` of them: service/run/replay_shards.py)
  ├─ weight broadcaster (Ray actor behind the learner's BroadcastPublisher)
  ├─ step budget        (Ray actor: each phase's env steps, claimed by the actors)
  ├─ N env actors       (Ray actors, the algorithm's behaviour) ──insert──▶ replay
  ├─ evaluator          (Ray actor, the behaviour's greedy policy)
  └─ learner loop       (this process) ◀──sample── replay, ──publish──▶ broadcaster

What differs between algorithms (phases, tables' columns, learner, behaviour) comes
from the algorithm's builder (service/run/registry.py); this module knows none of them.
A reproducible run (`reproducible: true`) has the learner drive the actors in lock-step
instead (service/run/lockstep.py).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import secrets
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import ray
import torch
from ray.exceptions import RayActorError
from tqdm import tqdm

from actors.env_actor import EnvActor, Segment
from actors.evaluator import RemoteEvaluator
from actors.transitions import replay_signature
from learner.agent import Phase
from learner.device import CompileMode, device_name, resolve_compile, resolve_device
from learner.loop import LearnerLoop, Lockstep, LoopSettings, LoopState
from service.core import Behaviour, Evaluation, SampleStream
from service.metrics import MetricsLogger, plot_learning_curve
from service.run.budget import StepBudget
from service.run.clients import actor_env, evaluator_env, world_clients
from service.run.config import TrainConfig
from service.run.lockstep import ActorRing, deterministic, stalled
from service.run.preflight import check_cluster, check_fits_locally, check_run_dir, check_task
from service.run.provenance import config_record
from service.run.registry import make_builder
from service.run.replay_folder import open_replay, reusable
from service.run.replay_shards import RunReplay
from service.run.resume import restore, resume_with
from service.run.supervision import ActorFleet, Supervisor
from service.run.validation import ConfigError
from service.weights import BroadcastPublisher

# Reference levels drawn on learning curves (measured with `graft eval`, 100 episodes).
REFERENCE_LEVELS = {"Pendulum-v1": {"hard-coded policy": -429.0}}


def table_spec(
    phase: Phase,
    *,
    signature: dict[str, Any],
    max_size: int,
    slack_env_steps: int,
    seed: Optional[int] = None,
) -> dict[str, Any]:
    """The replay table of one phase, its rate limiter holding the phase's update ratio
    and its sampler seeded with `seed` (None: fresh entropy)."""
    if phase.samples_per_insert is None:
        limiter: dict[str, Any] = {"kind": "min_size", "min_size": phase.min_size}
    else:
        limiter = {
            "kind": "sample_to_insert_ratio",
            "samples_per_insert": phase.samples_per_insert,
            "min_size": phase.min_size,
            "error_buffer": slack_env_steps * phase.samples_per_insert,
            "sample_credit": phase.sample_credit,
        }
    spec = {"name": phase.name, "max_size": max_size, "signature": signature}
    if seed is not None:
        spec["seed"] = seed
    if phase.sequence_length > 1:
        spec["max_sequence_length"] = phase.sequence_length
    return {**spec, "rate_limiter": limiter}


def _signature(config: TrainConfig, behaviour: Behaviour) -> dict[str, Any]:
    env = config.make_env()
    signature = replay_signature(env.observation_space, behaviour.columns())
    env.close()
    return signature


def preset_tables(
    config: TrainConfig,
    *,
    phases: Optional[list[Phase]] = None,
    signature: Optional[dict[str, Any]] = None,
) -> list[dict[str, Any]]:
    """Every replay table a preset's run uses, one per phase (built when not given)."""
    if phases is None or signature is None:
        builder = make_builder(config)
        behaviour = builder.make_behaviour(num_actors=config.num_actors)
        phases, signature = builder.phases(), _signature(config, behaviour)
    return [
        table_spec(
            p,
            signature=signature,
            max_size=config.replay_max_size,
            slack_env_steps=config.slack_env_steps,
            seed=int(np.random.SeedSequence([config.seed, i]).generate_state(1)[0]),
        )
        for i, p in enumerate(phases)
    ]


def transition_table_spec(config: TrainConfig) -> dict[str, Any]:
    """The table of a preset's last (online) phase, e.g. for `graft replay serve --preset`."""
    return preset_tables(config)[-1]


RETRIES_ACROSS_RESTART = 40
"""Retries of a replay call that finds no server (backoff up to 2 s: over a minute), so
actors and the learner wait out a replay server's restart."""

ACTOR_FINISH_S = 60.0
"""How long actors may take to send their last batches once the learner is done."""

PENDING_INSERTS = 8
"""Insert batches an actor may queue for a table that never holds inserts back."""


def start_replay(
    tables: list[dict[str, Any]],
    config: TrainConfig,
    *,
    host: str,
    token: Optional[str],
    run_dir: Path,
) -> RunReplay:
    """The run's replay servers (`replay.shards` of them), supervised, with clients that
    connect from any node (the node's address when they listen on the network)."""
    return RunReplay(
        tables,
        shards=config.replay.shards,
        host=host,
        port=config.replay.port,
        token=token,
        run_dir=run_dir,
        checkpoint_every_s=config.replay.checkpoint_every_s,
        max_restarts=config.replay.max_restarts,
        advertise=ray.util.get_node_ip_address() if host == "0.0.0.0" else None,
        # Resends keep their sequence numbers, so retrying through a restart doubles nothing.
        max_retries=RETRIES_ACROSS_RESTART,
    )


def _segments(phases: list[Phase], num_actors: int) -> list[Segment]:
    """Each actor's share of every phase's env steps (rounded up); with `num_actors=1`
    the whole phases, as actors drawing on a shared `StepBudget` are given them. A phase
    whose table holds a samples-per-insert ratio has each insert waited for, so the rate
    limiter paces acting; a `min_size` table takes a queue of inserts."""
    return [
        Segment(
            p.name,
            -(-p.env_steps // num_actors),
            -(-p.warmup_steps // num_actors),
            pending_inserts=0 if p.samples_per_insert is not None else PENDING_INSERTS,
        )
        for p in phases
        if p.env_steps > 0
    ]


def connect_ray(address: str) -> bool:
    """Starts a new local Ray instance ('local', whatever RAY_ADDRESS says) or joins a
    cluster ('auto', host:port, ray://host:port); True if we started it."""
    if ray.is_initialized():
        return False
    with _keeping_sigterm():
        if address == "local":
            ray.init(
                address="local",
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
            return True
        _use_token_auth(address)
        ray.init(address=address, log_to_driver=False)
        return False


@contextlib.contextmanager
def _keeping_sigterm() -> Iterator[None]:
    """Ray's driver installs its own SIGTERM handler (it logs a stack and exits); put
    back the one `graft train` set, so SIGTERM still stops a run as Ctrl-C does."""
    on_main = threading.current_thread() is threading.main_thread()
    previous = signal.getsignal(signal.SIGTERM) if on_main else None
    try:
        yield
    finally:
        if callable(previous) or previous == signal.SIG_IGN:
            signal.signal(signal.SIGTERM, previous)


def _use_token_auth(address: str) -> None:
    """Joins a cluster at HOST:PORT or ray://HOST:PORT with Ray's token auth when this
    machine holds a token.

    Ray turns token auth on by itself only for 'auto'; with an explicit address a
    cluster whose nodes require the token (RAY_AUTH_MODE=token) would refuse us after
    many retries (Ray Client's server too: "ray client connection timeout"). An
    explicit RAY_AUTH_MODE (e.g. 'disabled') is left as it is.
    """
    if "RAY_AUTH_MODE" in os.environ:
        return
    token_file = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    if os.environ.get("RAY_AUTH_TOKEN") or Path(token_file).is_file():
        try:  # sets RAY_AUTH_MODE=token and reloads Ray's cached config, as 'auto' does
            from ray._private.authentication.authentication_token_setup import (
                _enable_token_auth,
            )
        except ImportError:  # another Ray version: its config reads the variable at start
            os.environ["RAY_AUTH_MODE"] = "token"
        else:
            _enable_token_auth()


def resolve_address(given: Optional[str]) -> tuple[str, Optional[str]]:
    """The Ray address a run uses: `given`, else RAY_ADDRESS, else 'local'; and, when
    RAY_ADDRESS decided it, one line saying so (it must not change a run silently)."""
    if given is not None:
        return given, None
    from_env = os.environ.get("RAY_ADDRESS")
    if from_env:
        return from_env, (
            f"joining the Ray cluster at RAY_ADDRESS={from_env}; --address local starts a "
            "new local Ray instead"
        )
    return "local", None


def _probe(config: TrainConfig) -> tuple[Any, Any, dict[str, Any]]:
    """The run's builder, its behaviour and the replay signature, built from one env probe.

    Raises:
        ConfigError: the env or an algorithm refuses the config (spaces, env_kwargs, a
            missing teacher), in one line.
    """
    import gymnasium as gym

    check_task(config)
    try:
        builder = make_builder(config)  # imports the task, refusing what the method cannot use
        behaviour = builder.make_behaviour(num_actors=config.num_actors)
        return builder, behaviour, _signature(config, behaviour)
    except (ValueError, FileNotFoundError, gym.error.Error) as e:
        raise ConfigError(str(e).splitlines()[0] if str(e) else type(e).__name__) from None


def learner_device(config: TrainConfig) -> tuple[torch.device, CompileMode]:
    """The device and compile mode the preset's ``learner`` section means here; ``auto``
    says in one line what it picked.

    Raises:
        ConfigError: a CUDA device this process does not see, or CUDA graphs without one.
    """
    try:
        device = resolve_device(config.learner.device)
        compile_mode = resolve_compile(config.learner.compile, device)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    if config.learner.device == "auto":
        _print(f"learner.device=auto picked {device} ({device_name(device)})")
    return device, compile_mode


@dataclass
class RunResult:
    """What a finished (or interrupted) run reports (also written to summary.json)."""

    run_dir: Path
    summary: dict[str, Any]
    evaluations: list[Evaluation]
    interrupted: bool = False
    """Ctrl-C stopped the run; its last checkpoint holds the state at `summary['env_steps']`."""


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

    Raises:
        ConfigError: a bad value, a refused run folder or resume, in one line.
    """
    if address.startswith("ray://"):  # outside the cluster: the run goes into it
        from service.run.on_cluster import train_on_cluster

        return train_on_cluster(config, address=address, run_dir=run_dir, resume=resume)
    run_dir, checkpoint = check_run_dir(config, run_dir, resume)
    check_fits_locally(config, address)
    device, compile_mode = learner_device(config)  # a GPU that is not here: refused before Ray
    clients = world_clients(config)
    torch.set_num_threads(1)  # the learner shares 2 cores with actors and the replay server
    start = time.perf_counter()
    builder, behaviour, signature = _probe(config)
    algorithm = builder.make_learner(device=device, compile=compile_mode)
    state, phases = LoopState(), builder.phases()
    # A phase's table does not depend on its budget: a resumed run serves the same one.
    tables = preset_tables(config, phases=phases, signature=signature)
    if checkpoint is not None:
        refill = config.reproducible or not reusable(run_dir, tables)
        state = restore(algorithm, checkpoint, phases, config, refill=refill)
    run_dir.mkdir(parents=True, exist_ok=True)
    hardware = {"learner_device": str(device), "learner_device_name": device_name(device)}
    (run_dir / "config.yaml").write_text(config_record(config, hardware=hardware))
    if checkpoint is not None:
        print(f"resumed from {checkpoint} at {state.updates} updates, {state.env_steps} env steps")
    started_ray = connect_ray(address)
    actors: Optional[ActorFleet] = None
    replay: Optional[RunReplay] = None
    supervisor: Optional[Supervisor] = None
    publisher: Optional[BroadcastPublisher] = None
    evaluator: Optional[RemoteEvaluator] = None
    interrupted, release_sigint = False, _no_op
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
        publisher = BroadcastPublisher()
        notes: list[str] = []
        say = _say_and_keep(notes, progress)
        evaluator = RemoteEvaluator(
            env=evaluator_env(config, clients),
            behaviour=builder.make_behaviour(num_actors=1),
            seed=10_000 + config.seed,
            options=config.evaluator.ray_options(),
            max_restarts=config.evaluator.max_restarts,
            on_restart=say,
        )
        resumed_env_steps = state.env_steps  # a restored table's env steps (resume_with)

        def make_actor(i: int, incarnation: int) -> Any:
            # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
            options = EnvActor.options(  # type: ignore[attr-defined]
                **config.actors.ray_options(), max_concurrency=2
            )
            return options.remote(
                env=actor_env(config, clients, i),
                num_envs=config.envs_per_actor,
                # A replacement explores from other seeds than the actor it replaces.
                seed=config.seed * 1000 + i * config.envs_per_actor + 100_000 * incarnation,
                replay=replay.writer(i),
                weights=publisher.subscriber(),
                behaviour=behaviour,
                steps_per_insert=config.steps_per_insert,
                async_envs=config.async_envs,
                nice=config.actor_nice,
            )

        # Asynchronous: every actor claims the steps of each phase from one shared budget,
        # an insert batch at a time, until the phase's budget is spent (so none idles
        # while others act); a dead one is replaced. Reproducible: each has a fixed share,
        # and the learner asks them for one insert batch at a time (ActorRing) and draws
        # each batch only when it needs it; wall-clock metrics go to timing.csv, not
        # metrics.csv. A dead actor there ends the run (a replacement would change what
        # the seed computes).
        segments = _segments(phases, config.num_actors)
        budget = None
        if not config.reproducible:
            # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
            budget = StepBudget.remote({s.table: s.steps for s in _segments(phases, 1)})  # type: ignore[attr-defined]
        actors = ActorFleet(
            make_actor,
            segments if budget is None else _segments(phases, 1),
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
        )
        bar = tqdm(
            total=sum(p.updates for p in phases),
            initial=state.updates,
            unit="upd",
            disable=not progress,
            dynamic_ncols=True,
        )

        faults = _FaultLog(logger, supervisor, evaluator)

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
            else lambda: _watch(supervisor, actors, faults, loop.state),
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
        loop.checkpoint()  # with the env-step count a resume continues from
        faults.log(final, always=True)
        _log_behaviour_stats(logger, actor_reports, config.num_actors, resumed_env_steps)
        logger.close()
        summary = _summarise(config, final, actor_reports, time.perf_counter() - start)
        if config.replay.shards > 1:
            summary["replay_shard_inserts"] = replay.inserts()
        summary["interrupted"] = interrupted
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
    finally:
        if supervisor is not None:
            supervisor.stop()
        if actors is not None:
            actors.kill()
        if evaluator is not None:
            evaluator.close()
        if publisher is not None:
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


def _check_actors(runs: list[Any]) -> None:
    """Raises the error of an actor that failed; the learner would otherwise wait forever.
    An actor that died (its process or node gone) is the supervisor's to replace."""
    finished, _ = ray.wait(runs, num_returns=len(runs), timeout=0)
    for ref in finished:
        try:
            ray.get(ref)  # re-raises the actor's exception, with its traceback
        except RayActorError:
            return  # being replaced: its share is not done
    if len(finished) == len(runs):
        raise RuntimeError(
            "every actor finished, but the learner is still waiting for sampled batches: "
            "the rate limiter and the update budget disagree (see replay.log, or each "
            "shard's replay-shard-K.log)"
        )


def _say_and_keep(notes: list[str], progress: bool) -> Callable[[str], None]:
    """A `note` that prints a fault line at once (above the progress bar) and keeps it."""

    def say(line: str) -> None:
        notes.append(line)
        message = f"graft train: {line}"
        if progress:
            tqdm.write(message, file=sys.stderr)
        else:
            print(message, file=sys.stderr, flush=True)

    return say


class _FaultLog:
    """Logs the restart counters (`faults/...`) with the learner's metrics when they change."""

    def __init__(self, logger: MetricsLogger, supervisor: Supervisor, evaluator: Any) -> None:
        self.logger, self.supervisor, self.evaluator = logger, supervisor, evaluator
        self._last: dict[str, float] = {}

    def log(self, s: LoopState, *, always: bool = False) -> None:
        counters = {
            **self.supervisor.counters(),
            "faults/evaluator_restarts": self.evaluator.restarts,
        }
        if always or counters != self._last:
            self.logger.log(counters, env_steps=s.env_steps, updates=s.updates)
            self._last = counters


def _watch(supervisor: Supervisor, fleet: ActorFleet, faults: _FaultLog, s: LoopState) -> None:
    """The learner waits for a batch: a fault the supervisor could not mend, or actors that
    all finished while the learner still waits, end the run with their reason."""
    supervisor.raise_error()
    faults.log(s)
    _check_actors(fleet.runs)


def _window(phase: Phase) -> dict[str, int]:
    """Sampling arguments for a phase: windows of k steps when it asks for them."""
    return {"sequence_length": phase.sequence_length} if phase.sequence_length > 1 else {}


def _log_behaviour_stats(
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


def _summarise(
    config: TrainConfig, s: LoopState, reports: list[dict[str, Any]], wall: float
) -> dict[str, Any]:
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
