"""graft as a user gets it: `python -m build` makes an sdist and a wheel from it; the wheel,
installed (not editable) into a fresh virtual environment, lists its presets and trains.

Minutes (a venv, its dependencies from pip's cache, a Ray run), so `make test-wheel` runs it,
not `make test`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest
import torch

import service

ROOT = Path(__file__).resolve().parents[2]
PROCESS_LIMIT_S = 600
"""Bound on each step (a build, an install, the run): a hang fails, never blocks CI."""

WHEEL_FILES = {
    "graft/presets/pendulum-td3.yaml",
    "graft/presets/minecraft-backbone.yaml",
    "service/replay/_proto/replay.proto",
    "service/replay/_proto/replay_pb2.py",
    "service/replay/_proto/replay_pb2.pyi",
    "service/replay/_proto/replay_pb2_grpc.py",
    "minecraft/malmo/obtain_diamond.xml",
    "graft/__init__.py",
}
SDIST_FILES = {"LICENSE", "pyproject.toml", "protos/graft/replay/v1/replay.proto"}

pytestmark = [pytest.mark.slow, pytest.mark.service, pytest.mark.wheel]


def _run(argv: list[str], *, cwd: Path, env: dict[str, str]) -> str:
    """Runs `argv`, bounded; its stdout, or a failure that shows its output."""
    done = subprocess.run(
        argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=PROCESS_LIMIT_S
    )
    assert done.returncode == 0, f"{argv}: exit {done.returncode}\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.fixture(scope="module")
def dist(tmp_path_factory) -> Path:
    """The sdist and the wheel `python -m build` makes (the wheel built from the sdist)."""
    out = tmp_path_factory.mktemp("dist")
    _run(
        [sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(ROOT)],
        cwd=ROOT,
        env=dict(os.environ),
    )
    return out


def test_the_wheel_and_sdist_carry_data_license_and_one_version(dist) -> None:
    version = service.__version__
    (wheel,) = dist.glob(f"graft_rl-{version}-py3-none-any.whl")
    (sdist,) = dist.glob(f"graft_rl-{version}.tar.gz")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert WHEEL_FILES <= names, WHEEL_FILES - names
    assert f"graft_rl-{version}.dist-info/licenses/LICENSE" in names
    assert not {n for n in names if n.startswith(("tests/", "examples/", "bench/"))}
    metadata = zipfile.ZipFile(wheel).read(f"graft_rl-{version}.dist-info/METADATA").decode()
    assert f"\nVersion: {version}\n" in metadata
    assert "\nLicense-Expression: Apache-2.0\n" in metadata
    assert "Requires-Dist: protobuf<9,>=7.35.1" in metadata
    with tarfile.open(sdist) as archive:
        members = {m.split("/", 1)[1] for m in archive.getnames() if "/" in m}
    assert SDIST_FILES <= members, SDIST_FILES - members


@pytest.mark.timeout(3 * PROCESS_LIMIT_S)
def test_the_wheel_installs_in_a_fresh_venv_and_trains_pendulum(dist, tmp_path) -> None:
    (wheel,) = dist.glob("graft_rl-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    # The user's shell: no PYTHONPATH (graft must come from the wheel) and no cluster to join.
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "RAY_ADDRESS"}}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env['PATH']}"
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
    # This venv's torch build first (the CPU one on a machine without a GPU), as `make setup`
    # does: the wheel's range then never pulls another.
    _run([*pip, f"torch=={torch.__version__}"], cwd=tmp_path, env=env)
    _run([*pip, str(wheel)], cwd=tmp_path, env=env)

    where = _run([str(venv / "bin" / "python"), "-c", "import service; print(service.__file__)"],
                 cwd=tmp_path, env=env)  # fmt: skip
    assert Path(where.strip()).is_relative_to(venv), where
    assert _run(["graft", "--version"], cwd=tmp_path, env=env) == f"graft {service.__version__}\n"
    presets = _run(["graft", "presets"], cwd=tmp_path, env=env)
    assert "pendulum-td3" in presets and "minecraft-backbone" in presets

    run_dir = tmp_path / "run"
    _run(
        ["graft", "train", "--preset", "pendulum-td3", "--env-steps", "1500", "--actors", "1",
         "--address", "local", "--run-dir", str(run_dir), "--no-progress"],
        cwd=tmp_path, env=env,
    )  # fmt: skip
    summary = json.loads((run_dir / "summary.json").read_text())
    assert 1500 - 200 <= summary["env_steps"] <= 1500, summary
    assert summary["updates"] > 0
