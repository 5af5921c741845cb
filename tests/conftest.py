"""Shared fixtures: a real replay server process and a real local Ray instance; the user
task of tests/fixtures/usertask and the projects in examples/ installed as their own
distributions; the markers that split the suite into its quick subset and the rest.

A test that starts Ray or a server process is marked ``service`` (tests using the
``ray_local``, ``replay_server`` or ``replay_client`` fixtures are marked here; others say
so themselves). ``make test-fast`` runs what is left with ``GRAFT_TEST_FAST=1``, under
which starting Ray or a subprocess fails the test, so a missing mark cannot go unnoticed.
"""

from __future__ import annotations

import fcntl
import importlib.util
import os
import site
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import ray
import torch

from graft.orchestration.ray_session import LOCAL_STARTS, start_local, start_retrying
from graft.replay_host.process import ReplayProcess
from service.replay.client import ReplayClient

TESTS = Path(__file__).resolve().parent
USERTASK = TESTS / "fixtures" / "usertask"
"""A user's own task package, which graft never imports (tests/graft/test_own_task)."""
USER_PACKAGES = {
    "usertask": USERTASK,
    "mountaincar_example": TESTS.parent / "examples" / "mountaincar",
    "cartpole_example": TESTS.parent / "examples" / "cartpole",
    "lunarlander_example": TESTS.parent / "examples" / "lunarlander",
    "halfcheetah_example": TESTS.parent / "examples" / "halfcheetah",
    "heldout_example": TESTS.parent / "examples" / "heldout",
}
"""Packages of graft's users (module: project folder), each its own distribution."""


def pytest_sessionstart(session: pytest.Session) -> None:
    """Installs each user package (``pip install -e``, as a user would) when it is not
    installed from its folder yet (`make test` does it before pytest starts), one pytest
    process at a time: `make test` starts two, and two pip installs of one package at once
    fail."""
    with open(Path(sys.prefix) / ".graft-test-packages.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        for module, folder in USER_PACKAGES.items():
            importlib.invalidate_caches()  # another process may have installed it meanwhile
            spec = importlib.util.find_spec(module)
            if spec is not None and spec.origin and Path(spec.origin).is_relative_to(folder):
                continue
            subprocess.run(
                [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "-e", str(folder)],
                check=True,
            )
            # This process read site-packages' .pth files before the install: read the new
            # one (addpackage skips folders already on sys.path).
            for site_folder in site.getsitepackages():
                for pth in Path(site_folder).glob("__editable__.*.pth"):
                    site.addpackage(site_folder, pth.name, None)  # type: ignore[attr-defined]


if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)  # several workers share the cores: one torch thread each

SERVICE_FIXTURES = {"ray_local", "replay_server", "replay_client"}
"""Fixtures that start Ray or a server process: their tests are ``service`` tests."""
QUICK = os.environ.get("GRAFT_TEST_FAST") == "1"
"""Set by ``make test-fast``: the quick subset, where Ray and subprocesses are refused."""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Marks the tests that use a fixture starting Ray or a server process ``service``."""
    for item in items:
        if SERVICE_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.service)


class NotInTheFastSubset(RuntimeError):
    """A test of the quick subset started Ray or a process: mark it ``service``."""


_running: list[pytest.Item] = []
"""The test being set up, run or torn down (its fixtures included)."""


def pytest_runtest_setup(item: pytest.Item) -> None:
    _running[:] = [item]


def pytest_configure(config: pytest.Config) -> None:
    """Under ``GRAFT_TEST_FAST=1``, Ray and subprocesses are refused in unmarked tests,
    from the first fixture a test sets up (module-scoped ones too) to its teardown."""
    if not QUICK:
        return
    popen_init, ray_init = subprocess.Popen.__init__, ray.init

    def guarded(what: str, start: Callable[..., Any]) -> Callable[..., Any]:
        def checked(*args: Any, **kwargs: Any) -> Any:
            if _running and not _running[0].get_closest_marker("service"):
                raise NotInTheFastSubset(
                    f"{_running[0].nodeid} starts {what}: mark it @pytest.mark.service"
                )
            return start(*args, **kwargs)

        return checked

    subprocess.Popen.__init__ = guarded("a subprocess", popen_init)  # type: ignore[method-assign]
    ray.init = guarded("Ray", ray_init)


PENDULUM_SIGNATURE = {
    "obs": {"dtype": "float32", "shape": [3]},
    "action": {"dtype": "float32", "shape": [1]},
    "reward": {"dtype": "float32", "shape": []},
    "terminated": {"dtype": "bool", "shape": []},
    "truncated": {"dtype": "bool", "shape": []},
    "next_obs": {"dtype": "float32", "shape": [3]},
    "log_prob": {"dtype": "float32", "shape": []},
    "policy_version": {"dtype": "int64", "shape": []},
}


def pendulum_batch(n: int, start: int = 0) -> dict[str, np.ndarray]:
    """Transitions whose every column encodes its index, so a sampled row can be checked."""
    i = np.arange(start, start + n)
    return {
        "obs": np.stack([i, i + 0.5, i + 0.25], axis=1).astype(np.float32),
        "action": (i[:, None] * 0.001).astype(np.float32),
        "reward": (-i).astype(np.float32),
        "terminated": i % 7 == 0,
        "truncated": i % 5 == 0,
        "next_obs": np.stack([i + 1, i + 1.5, i + 1.25], axis=1).astype(np.float32),
        "log_prob": (i * -0.5).astype(np.float32),
        "policy_version": i.astype(np.int64),
    }


@pytest.fixture
def replay_server():
    """A replay server child process with one 'transitions' table of 1,000 items."""
    tables = [{"name": "transitions", "max_size": 1000, "signature": PENDULUM_SIGNATURE}]
    with ReplayProcess(tables) as server:
        yield server


@pytest.fixture
def replay_client(replay_server) -> ReplayClient:
    client = ReplayClient(replay_server.address, max_retries=0)
    yield client
    client.close()


@pytest.fixture(scope="session")
def ray_local():
    """One real local Ray instance for the whole test session (started again, as `graft
    train` does, if its GCS does not answer in time on a loaded machine)."""
    start_retrying(lambda: start_local(num_cpus=2), tries=LOCAL_STARTS)
    yield
    ray.shutdown()
