"""Shared fixtures: a real replay server process and a real local Ray instance; the user
task of tests/fixtures/usertask and the projects in examples/ installed as their own
distributions."""

from __future__ import annotations

import importlib.util
import site
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import ray

from service.replay.client import ReplayClient
from service.run.replay_host.process import ReplayProcess

TESTS = Path(__file__).resolve().parent
USERTASK = TESTS / "fixtures" / "usertask"
"""A user's own task package, which graft never imports (tests/service/run/test_own_task)."""
USER_PACKAGES = {
    "usertask": USERTASK,
    "mountaincar_example": TESTS.parent / "examples" / "mountaincar",
    "cartpole_example": TESTS.parent / "examples" / "cartpole",
}
"""Packages of graft's users (module: project folder), each its own distribution."""


def pytest_sessionstart(session: pytest.Session) -> None:
    """Installs each user package (``pip install -e``, as a user would) when it is not
    installed from its folder yet; `make test` does it before pytest starts."""
    for module, folder in USER_PACKAGES.items():
        spec = importlib.util.find_spec(module)
        if spec is not None and spec.origin and Path(spec.origin).is_relative_to(folder):
            continue
        subprocess.run(
            [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "-e", str(folder)],
            check=True,
        )
        # This process read site-packages' .pth files before the install: read the new one
        # (addpackage skips folders already on sys.path).
        for site_folder in site.getsitepackages():
            for pth in Path(site_folder).glob("__editable__.*.pth"):
                site.addpackage(site_folder, pth.name, None)  # type: ignore[attr-defined]
        importlib.invalidate_caches()


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
    """One real local Ray instance for the whole test session."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()
