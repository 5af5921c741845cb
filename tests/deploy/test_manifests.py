"""deploy/'s YAML files parse, and the commands in them name things that exist."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest
import yaml

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"


def test_cluster_yaml_copies_the_token_and_starts_nodes_with_the_script() -> None:
    config = yaml.safe_load((DEPLOY / "cluster.yaml").read_text())
    assert config["file_mounts"]["/home/ubuntu/.ray/auth_token"] == "~/.ray/auth_token"
    starts = config["head_start_ray_commands"] + config["worker_start_ray_commands"]
    assert sum("deploy/ray-node.sh" in c for c in starts) == 2
    assert not any("token" in c and "auth_token" not in c and "RAY_AUTH_MODE" not in c
                   for c in starts)  # fmt: skip


def test_kuberay_rayjob_mounts_the_token_secret_on_every_pod() -> None:
    (job,) = yaml.safe_load_all((DEPLOY / "kuberay.yaml").read_text())
    assert (job["apiVersion"], job["kind"]) == ("ray.io/v1", "RayJob")
    assert job["spec"]["entrypoint"].startswith("graft train --preset pendulum-td3")
    spec = job["spec"]["rayClusterSpec"]
    pods = [spec["headGroupSpec"]["template"]["spec"]] + [
        g["template"]["spec"] for g in spec["workerGroupSpecs"]
    ]
    for pod in pods:
        (container,) = pod["containers"]
        env = {e["name"]: e["value"] for e in container["env"]}
        assert env["RAY_AUTH_MODE"] == "token"
        mounts = {m["name"]: m["mountPath"] for m in container["volumeMounts"]}
        assert env["RAY_AUTH_TOKEN_PATH"].startswith(mounts["ray-token"])
        assert pod["volumes"][0]["secret"]["secretName"] == "graft-ray-token"
    assert spec["headGroupSpec"]["rayStartParams"]["num-cpus"] == "0"


@pytest.mark.service
def test_the_node_script_refuses_a_missing_role_in_one_line() -> None:
    result = subprocess.run(
        ["bash", str(DEPLOY / "ray-node.sh")], capture_output=True, text=True, check=False
    )
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "ray-node.sh: give a role: head, worker or copy-token (see the top of this file)"
    ]
    syntax = subprocess.run(["bash", "-n", str(DEPLOY / "ray-node.sh")], capture_output=True)
    assert syntax.returncode == 0, syntax.stderr


def test_the_dockerfile_installs_cpu_torch_and_bakes_in_no_token() -> None:
    text = (DEPLOY / "Dockerfile").read_text()
    assert "download.pytorch.org/whl/cpu" in text
    assert "auth_token" not in text.replace("# Ray's token", "")
    for line in text.splitlines():
        if line.startswith("COPY ") and not line.startswith("COPY pyproject"):
            assert (DEPLOY.parent / line.split()[1]).exists(), line


@pytest.mark.service
@pytest.mark.parametrize(
    ("docker", "settings", "refusal"),
    [
        (
            "false",  # a docker that has no such image and pulls nothing
            ["BASE=graft-no-such-base:0"],
            "make image: BASE=graft-no-such-base:0 is neither a local image nor pullable "
            "(deploy/make-base.sh makes one)",
        ),
        (
            "true",  # a docker that has every image: the CA check comes next
            ["BASE=graft-base:bookworm", "CA=/no/such/ca.crt"],
            "make image: CA=/no/such/ca.crt: no such file",
        ),
    ],
)
def test_make_image_refuses_a_bad_base_or_ca_in_one_line(docker, settings, refusal, tmp_path):
    """The Makefile's own checks, before any build (docker is `false` or `true` here: the
    checks are the Makefile's; test_containers.py builds with a real one)."""
    # As a user types it, also when the suite itself runs under make (`make test`).
    env = {k: v for k, v in os.environ.items() if k not in ("MAKELEVEL", "MAKEFLAGS", "MFLAGS")}
    result = subprocess.run(
        ["make", "-s", "-C", str(DEPLOY.parent), "image", f"DOCKER={docker}", *settings],
        capture_output=True, text=True, check=False, timeout=60, env=env,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    ours = [line for line in result.stderr.splitlines() if not line.startswith("make: ***")]
    assert ours == [refusal]


def _joined(text: str) -> str:
    """`text` with lines ending in a backslash joined and runs of spaces made one."""
    return re.sub(r"[ \t]+", " ", text.replace("\\\n", " "))


def test_the_readme_shows_the_image_commands_ci_runs():
    """deploy/README.md's image commands are those .ci/containers.sh runs, at its names."""
    readme = _joined((DEPLOY / "README.md").read_text())
    ci = _joined((DEPLOY.parent / ".ci" / "containers.sh").read_text())
    assert "BASE=${BASE:-graft-base:bookworm}" in ci
    pairs = {
        'deploy/make-base.sh "$BASE"': "sudo deploy/make-base.sh graft-base:bookworm",
        'make image IMAGE="$IMAGE" BASE="$BASE"': "make image BASE=graft-base:bookworm",
        "make test-containers IMAGE=": "make test-containers",
    }
    for in_ci, in_readme in pairs.items():
        assert in_ci in ci, in_ci
        assert in_readme in readme, in_readme


def test_the_readme_shows_the_kuberay_commands_of_the_manifest():
    readme = _joined((DEPLOY / "README.md").read_text())
    header = (DEPLOY / "kuberay.yaml").read_text().split("\napiVersion:")[0]
    commands = [_joined(line[1:].strip()) for line in header.splitlines() if line.startswith("#  ")]
    assert len(commands) == 3
    for command in commands:
        assert command in readme, command
