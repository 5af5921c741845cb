"""A real multi-node run: Ray nodes in Linux network namespaces joined by a bridge.

The test builds a head namespace (no CPUs: actors cannot run there) and worker namespaces,
each with its own address on a private bridge, starts Ray in them with `deploy/ray-node.sh`
(the commands of deploy/README.md, token auth on), and runs a tiny `pendulum-td3` from the
head with `--address HEAD_IP:6379` and its actors forced onto nodes labelled as workers.
Mid-run it kills one env actor and the replay server (SIGKILL); the run must finish its
update budget with replay data that holds no item twice.

Everything it creates carries this process's pid in its name (namespaces, bridge, Ray's
temp folder) and is torn down even when the test fails: the processes in its namespaces
(by pid), then the namespaces and the bridge.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from service.replay.server import durability

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
WORKERS = 2
RUN_LIMIT_S = 900.0
"""Only a guard against a hang: how long the run may take on a loaded machine."""


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


class NamespaceCluster:
    """A head and `workers` worker namespaces on one bridge, each running a Ray node."""

    def __init__(self, workers: int) -> None:
        pid = os.getpid()
        self.bridge = f"gb{pid}"
        self.namespaces = [f"gn{pid}n{i}" for i in range(workers + 1)]
        self.addresses = [
            f"10.{200 + pid % 50}.{pid // 50 % 250}.{i + 1}" for i in range(workers + 1)
        ]
        self.temp_dir = f"/tmp/graft-ray-{pid}"
        self.head = f"{self.addresses[0]}:6379"

    def build(self) -> None:
        """The bridge and namespaces; skips the test where namespaces cannot be made."""
        if os.geteuid() != 0 or shutil.which("ip") is None:
            pytest.skip("network namespaces need root and iproute2 (`ip netns`)")
        try:
            _ip("netns", "add", self.namespaces[0])
        except subprocess.CalledProcessError as error:
            pytest.skip(f"cannot create a network namespace: {error.stderr.strip()}")
        _ip("link", "add", self.bridge, "type", "bridge")
        _ip("link", "set", self.bridge, "up")
        for i, (ns, address) in enumerate(zip(self.namespaces, self.addresses, strict=True)):
            if i:
                _ip("netns", "add", ns)
            veth = f"{self.bridge}v{i}"
            _ip("link", "add", veth, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("link", "set", veth, "master", self.bridge, "up")
            _ip("-n", ns, "addr", "add", f"{address}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")
            _ip("-n", ns, "link", "set", "lo", "up")

    def env(self) -> dict[str, str]:
        return {
            **os.environ,
            "PATH": f"{BIN}:{os.environ.get('PATH', '')}",
            "PYTHONPATH": str(ROOT),
            "RAY": str(BIN / "ray"),
            # A raylet gives its agents 30 s to start by default; on a machine loaded by
            # other jobs their Python start-up takes longer.
            "RAY_agent_register_timeout_ms": "180000",
        }

    def exec(self, ns: str, argv: list[str], **kwargs: object) -> subprocess.Popen:
        return subprocess.Popen(["ip", "netns", "exec", ns, *argv], env=self.env(), **kwargs)  # type: ignore[call-overload]

    def start_ray(self) -> None:
        """deploy/ray-node.sh on every node, as deploy/README.md says."""
        script = str(ROOT / "deploy" / "ray-node.sh")
        head = [script, "head", "--ip", self.addresses[0], "--num-cpus", "0",
                "--temp-dir", self.temp_dir]  # fmt: skip
        self._start(self.namespaces[0], head)
        for ns, address in zip(self.namespaces[1:], self.addresses[1:], strict=True):
            worker = [script, "worker", "--head", self.head, "--ip", address, "--num-cpus", "2",
                      "--labels", "graft-node=worker", "--temp-dir", self.temp_dir]  # fmt: skip
            self._start(ns, worker)

    def _start(self, ns: str, argv: list[str], attempts: int = 5) -> None:
        """Starts a node; again (its namespace emptied first) if Ray's fixed 30 s wait for
        its raylet ran out on a loaded machine."""
        # Ray waits a fixed 30 s for a new raylet to register; on a machine loaded by other
        # jobs that runs out, so the nodes' control processes get a slightly higher priority.
        for attempt in range(attempts):
            process = self.exec(ns, ["nice", "-n", "-10", *argv], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)  # fmt: skip
            out, _ = process.communicate(timeout=300)
            if process.returncode == 0:
                return
            assert "timed out during startup" in out and attempt < attempts - 1, out
            self._kill(self.pids(ns))

    def _kill(self, pids: list[int]) -> None:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            for pid in pids:
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and any(Path(f"/proc/{p}").exists() for p in pids):
                time.sleep(0.2)

    def pids(self, ns: str) -> list[int]:
        result = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True)
        return [int(p) for p in result.stdout.split()]

    def find(self, ns: str, text: str) -> list[int]:
        """Pids in namespace `ns` whose command line contains `text`."""
        return [p for p in self.pids(ns) if text in _cmdline(p)]

    def tear_down(self) -> None:
        """Every process in the namespaces (by pid), then the namespaces and the bridge."""
        self._kill([p for ns in self.namespaces for p in self.pids(ns)])
        for ns in self.namespaces:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", self.bridge], capture_output=True)
        shutil.rmtree(self.temp_dir, ignore_errors=True)


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _metric(csv_path: Path, key: str) -> list[float]:
    with csv_path.open() as f:
        return [float(row["value"]) for row in csv.DictReader(f) if row["key"] == key]


@pytest.fixture
def cluster():
    made = NamespaceCluster(WORKERS)
    try:
        made.build()
        made.start_ray()
        yield made
    finally:
        made.tear_down()


@pytest.mark.timeout(RUN_LIMIT_S + 600)  # Ray's start on three nodes, then the run
def test_a_run_on_three_nodes_survives_a_dead_actor_and_replay_server(cluster, tmp_path):
    run_dir, env_steps, learning_starts = tmp_path / "run", 2000, 200
    argv = [
        str(BIN / "graft"), "train", "--preset", "pendulum-td3", "--address", cluster.head,
        "--run-dir", str(run_dir), "--no-progress", "--env-steps", str(env_steps),
        "--actors", "2", "--set", "envs_per_actor=2",
        "--set", f"learning_starts={learning_starts}", "--set", "eval_every=100000",
        "--set", "eval_episodes=1", "--set", "td3.hidden_sizes=[16, 16]",
        "--set", "td3.batch_size=32", "--set", "actors.label_selector={graft-node: worker}",
    ]  # fmt: skip
    train = cluster.exec(
        cluster.namespaces[0], argv, cwd=tmp_path, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + RUN_LIMIT_S
        metrics = run_dir / "metrics.csv"
        # Faults strike once the learner trains (its first metrics rows are written).
        while not (metrics.exists() and len(metrics.read_text().splitlines()) > 4):
            assert train.poll() is None, train.communicate()
            assert time.monotonic() < deadline, "the run did not start training"
            time.sleep(0.5)
        actors = {ns: cluster.find(ns, "ray::EnvActor") for ns in cluster.namespaces}
        assert actors[cluster.namespaces[0]] == [], "an actor ran on the 0-CPU head"
        on_workers = [p for ns in cluster.namespaces[1:] for p in actors[ns]]
        assert len(on_workers) == 2, actors
        os.kill(on_workers[0], signal.SIGKILL)
        time.sleep(2)
        (replay,) = cluster.find(cluster.namespaces[0], "service.run.replay_cli serve")
        os.kill(replay, signal.SIGKILL)
        _, err = train.communicate(timeout=max(deadline - time.monotonic(), 1))
    finally:
        if train.poll() is None:
            train.kill()
            train.wait()

    assert train.returncode == 0, err
    assert "env actor" in err and "restarted it" in err, err
    assert "replay server died" in err and "restarted from its checkpoint folder" in err, err
    assert _metric(metrics, "faults/actor_restarts")[-1] >= 1
    assert _metric(metrics, "faults/replay_restarts")[-1] >= 1
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == env_steps - learning_starts  # the learner's whole budget

    # The replay server's last checkpoint (written when the run stopped it) holds every
    # insert once: as many rows as inserts, and no row twice (a resent batch stored again
    # would repeat its rows exactly).
    folder = run_dir / "replay"
    newest = durability.checkpoint_path(folder, durability.checkpoint_numbers(folder)[-1])
    table = durability.read_checkpoint(newest).tables["transitions"]
    rows = np.concatenate(
        [table[f"col/{c}"].reshape(len(table["keys"]), -1) for c in ("obs", "action", "next_obs")],
        axis=1,
    )
    assert len(rows) == table["meta"]["inserts"] >= learning_starts
    assert len(np.unique(rows, axis=0)) == len(rows)
