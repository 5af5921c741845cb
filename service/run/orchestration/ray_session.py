"""Joining Ray: a new local instance or a cluster (with Ray's token auth when this machine
holds a token), keeping `graft train`'s SIGTERM handler, and which address a run uses."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Optional

import ray


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
