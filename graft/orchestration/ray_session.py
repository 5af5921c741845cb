"""Joining Ray: a new local instance or a cluster (with Ray's token auth when this machine
holds a token), keeping `graft train`'s SIGTERM handler."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Optional

import ray

from graft.validation import ConfigError

HEAD_ANSWER_S = 10.0
"""How long a cluster's head at HOST:PORT has to accept a connection."""
LOCAL_STARTS = 3
"""Tries at starting a local Ray instance: on a loaded machine its GCS may not answer
within the 5 s Ray's driver waits ("Failed to connect to GCS"), and a second try does."""


def connect_ray(address: str) -> bool:
    """Starts a new local Ray instance ('local', whatever RAY_ADDRESS says) or joins a
    cluster ('auto', host:port, ray://host:port); True if we started it."""
    if ray.is_initialized():
        return False
    with _keeping_sigterm():
        if address == "local":
            start_retrying(start_local, tries=LOCAL_STARTS)
            return True
        _use_token_auth(address)
        ray.init(address=address, log_to_driver=False)
        return False


IDLE_WORKERS_KEPT = 0
"""Idle worker processes a local instance keeps (Ray's `num_workers_soft_limit`; Ray's
default is one per CPU). An idle Ray worker costs about 1 % of a core (0.66 s of CPU a
minute measured here); graft's actors each start their own worker anyway, so past a
second idle, Ray ends any that no task or actor took."""


TASK_EVENTS_KEPT = 10_000
"""Task events a local instance's GCS keeps (Ray's `task_events_max_num_task_in_gcs`,
100,000 by default), the oldest overwritten past it. Each actor call is a task (a weight
publish, a budget claim, a report) and its events took about 3 MiB of the GCS's memory
per 1,000 calls, so a run's GCS grew by 130-170 MiB an hour until Ray's cap (about
330 MiB above its start); at 10,000 it levels off about 40 MiB above it (docs/results.md,
"A long run under faults"). $RAY_task_events_max_num_task_in_gcs, where set, wins."""


def _system_config() -> dict[str, int]:
    config = {"num_workers_soft_limit": IDLE_WORKERS_KEPT}
    if "RAY_task_events_max_num_task_in_gcs" not in os.environ:
        config["task_events_max_num_task_in_gcs"] = TASK_EVENTS_KEPT
    return config


def start_local(num_cpus: Optional[int] = None) -> None:
    """A new local Ray instance for this driver, without the parts it would not use: the
    dashboard, idle worker processes (`IDLE_WORKERS_KEPT`), the log monitor and the
    autoscaler's monitor. The log monitor tails every worker's log file ten times a second
    to forward new lines to drivers, and this driver takes none (log_to_driver=False); the
    files stay in Ray's session folder. The autoscaler's monitor would scale a cluster
    with a cluster config, which a one-machine instance has not: it costs 0.47 s of CPU to
    start and 0.1 s a minute (`ray status` on a cluster graft joins is unchanged). Its GCS
    keeps `TASK_EVENTS_KEPT` task events.
    `python bench/ray_idle.py` measures what an idle instance costs."""
    ray.init(
        address="local",
        num_cpus=num_cpus,
        include_dashboard=False,
        log_to_driver=False,
        configure_logging=False,
        _system_config=_system_config(),
    )
    node = ray._private.worker._global_node
    if node is not None:
        node.kill_log_monitor(check_alive=False)
        node.kill_monitor(check_alive=False)


def start_retrying(
    start: Callable[[], None], *, tries: int, stop: Callable[[], None] = ray.shutdown
) -> None:
    """`start()`, again (after `stop()`, which ends what the failed start left) while it
    fails with Ray's system error, at most `tries` times; each retry said in one line."""
    for attempt in range(1, tries + 1):
        try:
            start()
            return
        except ray.exceptions.RaySystemError as error:
            stop()
            if attempt == tries:
                raise
            print(
                f"local Ray did not start ({str(error).splitlines()[0][:120]}); "
                f"starting it again ({attempt + 1} of {tries})",
                file=sys.stderr,
            )


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


def check_head(address: str) -> None:
    """Refuses, in one line, a cluster join Ray would not make: a HOST:PORT where no head
    answers (Ray retries that for ever), or token auth (RAY_AUTH_MODE=token) without a
    token on this machine. 'local', 'auto' (Ray finds the node this machine runs, and its
    token) and 'ray://' addresses pass (Ray Client says itself).

    Raises:
        ConfigError: e.g. ``--address 10.0.0.1:6379: no Ray head answers there
            (connection refused) ...``.
    """
    if address in ("local", "auto") or address.startswith("ray://"):
        return
    if os.environ.get("RAY_AUTH_MODE") == "token" and not _has_token():
        raise ConfigError(
            f"--address {address}: token auth is on (RAY_AUTH_MODE=token) but this machine "
            f"has no Ray token: put the cluster's token in {_token_file()} "
            "(deploy/ray-node.sh copy-token USER@THIS_MACHINE), or name its file with "
            "RAY_AUTH_TOKEN_PATH"
        )
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(
            f"--address {address}: expected HOST:PORT (the head's, e.g. 10.0.0.1:6379), "
            "'auto', 'local' or ray://HOST:10001"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=HEAD_ANSWER_S).close()
    except OSError as error:
        why = (
            f"no answer within {HEAD_ANSWER_S:g} s"
            if isinstance(error, TimeoutError)
            else (error.strerror or str(error)).lower()
        )
        raise ConfigError(
            f"--address {address}: no Ray head answers there ({why}); start one there "
            "(deploy/ray-node.sh head, or `ray start --head`) or give its address"
        ) from None


def _token_file() -> str:
    """Where Ray looks for this machine's token file."""
    return os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")


def _has_token() -> bool:
    return bool(os.environ.get("RAY_AUTH_TOKEN")) or Path(_token_file()).is_file()


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
    if _has_token():
        try:  # sets RAY_AUTH_MODE=token and reloads Ray's cached config, as 'auto' does
            from ray._private.authentication.authentication_token_setup import (
                _enable_token_auth,
            )
        except ImportError:  # another Ray version: its config reads the variable at start
            os.environ["RAY_AUTH_MODE"] = "token"
        else:
            _enable_token_auth()
