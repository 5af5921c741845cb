"""Real multi-node runs: Ray nodes in Linux network namespaces joined by a bridge.

One cluster per module (Ray's start on three nodes is slow): a head namespace (no CPUs:
actors cannot run there), two worker namespaces labelled ``graft-node=worker``, and a
client namespace on the same bridge that is not a Ray node. Ray starts in them with
`deploy/ray-node.sh` (token auth on, the token in a file of this test's own). The test
runs the commands of deploy/README.md ("The same on one Linux machine"), with tiny
budgets added and the test's own namespace names and addresses:

- ``ray-node.sh head ...`` and ``ray-node.sh worker ...`` (the cluster fixture);
- ``graft train --preset pendulum-td3 --address HEAD:6379 ...`` from the head: SIGKILL
  one env actor and the replay server mid-run; the run must finish its update budget
  with replay data that holds no item twice;
- ``graft train --preset minecraft-backbone --address HEAD:6379 --clients 2 ...`` from the
  head: its actors and their simulated world servers run on the workers, one actor is
  SIGKILLed mid-run and replaced, the run finishes its updates;
- ``graft train --preset pendulum-td3 --address ray://HEAD:10001 ...`` from the client
  namespace, with a copy of the token (RAY_AUTH_TOKEN_PATH): the run goes into the
  cluster, its replay server runs on the head, its folder is where graft says.

`test_the_readme_shows_the_commands_this_module_runs` keeps README and test in sync; the
commands, the run a test watches and the placement checks are cluster_story's, shared with
the same story in containers (test_containers.py). Everything made carries this process's
pid in its name (namespaces, bridge, Ray's temp folder) and is torn down even when a test
fails: the processes in the namespaces (by pid), then the namespaces, the bridge and the
firewall rule that lets the bridge forward (where iptables is present: a running dockerd
sets the FORWARD chain's policy to DROP).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Optional

import numpy as np
import pytest

from service.replay.server import durability
from tests.deploy.cluster_story import (
    CLUSTER_CMDS,
    HEAD_CMD,
    MINECRAFT_CMD,
    MINECRAFT_TINY,
    MINECRAFT_UPDATES,
    PENDULUM_CMD,
    PENDULUM_TINY,
    RAY_CLIENT_CMD,
    REPLAY_SERVER,
    RUN_LIMIT_S,
    WORKER_CMD,
    Run,
    actors_on_workers,
    command,
    metric,
    one_line_refusal,
    readme_lacks,
    training,
    worlds_beside_their_actors,
)

# Three Ray nodes in network namespaces, with real-time waits: a minute and a half of both
# cores, run by `make test-long` (CI runs it after `make test`), one test at a time.
pytestmark = pytest.mark.long

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
WORKERS = 2
START_LIMIT_S = 900.0
"""Only a guard against a hang: how long Ray's start on three nodes may take."""
README_ADDRESSES = {"head": "10.99.0.1", "worker": "10.99.0.2", "client": "10.99.0.3"}


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True)


class NamespaceCluster:
    """A head and `workers` worker namespaces, each running a Ray node, and one client
    namespace (no Ray node), all on one bridge."""

    def __init__(self, workers: int) -> None:
        pid = os.getpid()
        self.bridge = f"gb{pid}"
        self.namespaces = [f"gn{pid}n{i}" for i in range(workers + 2)]
        self.addresses = [
            f"10.{200 + pid % 50}.{pid // 50 % 250}.{i + 1}" for i in range(workers + 2)
        ]
        self.head_ns, self.client_ns = self.namespaces[0], self.namespaces[-1]
        self.worker_ns = self.namespaces[1:-1]
        self.head_node, self.worker_nodes = self.head_ns, self.worker_ns
        self.forward_rule: Optional[list[str]] = None
        """The FORWARD rule this cluster added for its bridge (removed on tear-down)."""
        self.head_ip = self.addresses[0]
        self.head = f"{self.head_ip}:6379"
        self.temp_dir = f"/tmp/graft-ray-{pid}"
        self.home = Path(self.temp_dir) / "home"
        """The nodes' home folder: a ray:// run writes its folder there by default."""
        # The cluster's token, in a file of this test's own; the client namespace gets a
        # copy, as `deploy/ray-node.sh copy-token` gives one to a client machine.
        self.token = Path(self.temp_dir) / "auth_token"
        self.client_token = Path(self.temp_dir) / "client" / "auth_token"

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
        self._let_the_bridge_forward()

    def _let_the_bridge_forward(self) -> None:
        """Lets the bridge forward between its ports whatever the FORWARD chain's policy:
        once br_netfilter is loaded (dockerd loads it) bridged packets pass that chain, and
        dockerd sets its policy to DROP."""
        iptables = shutil.which("iptables")
        if iptables is None:
            return
        rule = ["FORWARD", "-i", self.bridge, "-o", self.bridge, "-j", "ACCEPT"]
        added = subprocess.run([iptables, "-I", *rule], capture_output=True, text=True)
        if added.returncode == 0:
            self.forward_rule = [iptables, "-D", *rule]

    def env(self, token: Path) -> dict[str, str]:
        return {
            **os.environ,
            "PATH": f"{BIN}:{os.environ.get('PATH', '')}",
            "PYTHONPATH": str(ROOT),
            "RAY": str(BIN / "ray"),
            "RAY_AUTH_TOKEN_PATH": str(token),
            "HOME": str(self.home),
            # A raylet gives its agents 30 s to start by default; on a machine loaded by
            # other jobs their Python start-up takes longer.
            "RAY_agent_register_timeout_ms": "180000",
        }

    def exec(
        self, ns: str, argv: list[str], *, token: Path | None = None, **kwargs: object
    ) -> subprocess.Popen:
        """Starts `argv` in namespace `ns`, its token file the node's or the client's copy."""
        if token is None:
            token = self.client_token if ns == self.client_ns else self.token
        return subprocess.Popen(  # type: ignore[call-overload]
            ["ip", "netns", "exec", ns, *argv], env=self.env(token), **kwargs
        )

    def run(self, ns: str, argv: list[str], cwd: Path, token: Optional[Path] = None) -> Run:
        """`graft train` (`argv`) started in namespace `ns`, watched."""
        pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True}
        return Run(lambda: self.exec(ns, argv, token=token, cwd=cwd, **pipes))

    def start_ray(self) -> None:
        """deploy/ray-node.sh on every node, as deploy/README.md says; then the token's
        copy for the client."""
        self.home.mkdir(parents=True)
        extra = ["--temp-dir", self.temp_dir]
        self._start(self.head_ns, command(HEAD_CMD, head=self.head_ip) + extra)
        for ns, address in zip(self.worker_ns, self.addresses[1:-1], strict=True):
            worker = command(WORKER_CMD, head=self.head_ip, worker=address)
            self._start(ns, worker + extra)
        self.client_token.parent.mkdir(mode=0o700)
        shutil.copy2(self.token, self.client_token)

    def _start(self, ns: str, argv: list[str], attempts: int = 5) -> None:
        """Starts a node; again (its namespace emptied first) if Ray's fixed 30 s wait for
        its raylet ran out on a loaded machine."""
        argv = [str(ROOT / argv[0]), *argv[1:]]
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

    def listening(self, ns: str) -> dict[int, list[str]]:
        """The TCP addresses each process of namespace `ns` listens on, by pid."""
        out = subprocess.run(["ip", "netns", "exec", ns, "ss", "-Hltnp"], capture_output=True,
                             text=True, check=True).stdout  # fmt: skip
        found: dict[int, list[str]] = {}
        for line in out.splitlines():
            fields = line.split()
            for pid in re.findall(r"pid=(\d+)", line):
                found.setdefault(int(pid), []).append(fields[3])
        return found

    def tear_down(self) -> None:
        """Every process in the namespaces (by pid), then the namespaces and the bridge."""
        self._kill([p for ns in self.namespaces for p in self.pids(ns)])
        for ns in self.namespaces:
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", self.bridge], capture_output=True)
        if self.forward_rule is not None:
            subprocess.run(self.forward_rule, capture_output=True)
        shutil.rmtree(self.temp_dir, ignore_errors=True)


def _graft(template: str, cluster: NamespaceCluster, *tiny: str) -> list[str]:
    argv = command(template, head=cluster.head_ip)
    return [str(BIN / "graft"), *argv[1:], "--no-progress", *tiny]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


@pytest.fixture(scope="module")
def cluster():
    made = NamespaceCluster(WORKERS)
    try:
        made.build()
        made.start_ray()
        yield made
    finally:
        made.tear_down()


def test_the_readme_shows_the_commands_this_module_runs():
    assert readme_lacks(c.format(**README_ADDRESSES) for c in CLUSTER_CMDS) == []


@pytest.mark.slow
@pytest.mark.timeout(START_LIMIT_S + RUN_LIMIT_S + 120)
def test_a_run_on_three_nodes_survives_a_dead_actor_and_replay_server(cluster, tmp_path):
    run_dir, env_steps, learning_starts = tmp_path / "run", 2000, 200
    argv = _graft(
        PENDULUM_CMD, cluster, "--run-dir", str(run_dir), "--env-steps", str(env_steps),
        "--set", "envs_per_actor=2", "--set", f"learning_starts={learning_starts}",
        "--set", "eval_every=100000", "--set", "eval_episodes=1",
        "--set", "td3.hidden_sizes=[16, 16]", "--set", "td3.batch_size=32",
    )  # fmt: skip
    train = cluster.run(cluster.head_ns, argv, tmp_path)
    metrics = run_dir / "metrics.csv"
    try:
        # Faults strike once the learner trains.
        train.wait_for(lambda: training(metrics), "start training")
        on_workers = list(actors_on_workers(cluster))
        os.kill(on_workers[0], signal.SIGKILL)
        time.sleep(2)
        (replay,) = cluster.find(cluster.head_ns, REPLAY_SERVER)
        os.kill(replay, signal.SIGKILL)
    finally:
        _, err = train.finish()

    assert train.process.returncode == 0, err
    assert "env actor" in err and "restarted it" in err, err
    assert "replay server died" in err and "restarted from its checkpoint folder" in err, err
    assert metric(metrics, "faults/actor_restarts")[-1] >= 1
    assert metric(metrics, "faults/replay_restarts")[-1] >= 1
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


@pytest.mark.slow
@pytest.mark.timeout(START_LIMIT_S + RUN_LIMIT_S + 120)
def test_minecraft_actors_and_their_worlds_run_on_workers_and_a_dead_one_is_replaced(
    cluster, tmp_path
):
    run_dir = tmp_path / "run"
    argv = _graft(MINECRAFT_CMD, cluster, "--run-dir", str(run_dir), *MINECRAFT_TINY)
    train = cluster.run(cluster.head_ns, argv, tmp_path)
    metrics = run_dir / "metrics.csv"
    try:
        train.wait_for(lambda: training(metrics), "start training")
        on_workers = actors_on_workers(cluster)
        worlds_beside_their_actors(cluster, on_workers)
        os.kill(next(iter(on_workers)), signal.SIGKILL)
    finally:
        _, err = train.finish()

    assert train.process.returncode == 0, err
    assert "env actor" in err and "restarted it" in err, err
    assert metric(metrics, "faults/actor_restarts")[-1] >= 1
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == MINECRAFT_UPDATES
    assert np.isfinite(summary["final_eval_return_mean"])


@pytest.mark.slow
@pytest.mark.timeout(START_LIMIT_S + RUN_LIMIT_S + 120)
def test_a_ray_client_run_from_a_machine_outside_the_cluster_runs_inside_it(cluster, tmp_path):
    # No --run-dir: the run's default folder, under the home folder of the head's Ray.
    runs = cluster.home / "runs"
    argv = _graft(RAY_CLIENT_CMD, cluster, *PENDULUM_TINY)
    train = cluster.run(cluster.client_ns, argv, tmp_path)
    try:
        train.wait_for(
            lambda: cluster.find(cluster.head_ns, f"{runs}/"), "start a replay server on the head"
        )
        (replay,) = cluster.find(cluster.head_ns, f"{runs}/")
        assert REPLAY_SERVER in _cmdline(replay)
        # The client runs only `graft train` (a Ray Client): no replay server, no Ray node.
        client = [_cmdline(p) for p in cluster.pids(cluster.client_ns)]
        assert not any(REPLAY_SERVER in c or "ray::" in c or "raylet" in c for c in client)
    finally:
        out, err = train.finish()

    assert train.process.returncode == 0, err
    said = re.search(f"the run ran on {re.escape(cluster.head_ip)}; its folder is there: (.+)", out)
    assert said is not None, out
    run_dir = Path(said[1])
    assert run_dir.parent == runs and run_dir.name.startswith("pendulum-td3-s0-"), run_dir
    assert f"run folder: {run_dir} " in out, out
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == 1000 - 200
    assert (run_dir / "replay").is_dir()  # the replay server's checkpoints, on the head


@pytest.mark.slow
@pytest.mark.timeout(START_LIMIT_S + 300)
def test_a_ray_client_without_the_token_is_refused_in_one_line(cluster, tmp_path):
    missing = tmp_path / "no-token"
    argv = _graft(RAY_CLIENT_CMD, cluster, "--run-dir", str(tmp_path / "run"))
    train = cluster.run(cluster.client_ns, argv, tmp_path, token=missing)
    _, err = train.finish()
    assert train.process.returncode == 2, err
    one_line_refusal(
        err,
        f"--address ray://{cluster.head_ip}:10001: Ray Client could not connect",
        f"the cluster's token in {missing}",
    )
    assert not (tmp_path / "run").exists()
