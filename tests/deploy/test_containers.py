"""A cluster in containers: Ray nodes in containers of deploy/Dockerfile's image.

The story of test_multinode.py (its commands and checks are cluster_story's), told with
containers on a user-defined bridge network instead of network namespaces: a head container
(no CPUs for actors) and two worker containers labelled ``graft-node=worker``, each with
the cluster's token mounted read-only, run deploy/README.md's commands ("A cluster in
containers"), in order:

- ``graft train --preset pendulum-td3 --address HEAD:6379 ...`` in the head: its actors on
  the workers, through the label selector;
- ``graft train --preset minecraft-backbone ...``: the actors' world servers run inside the
  worker containers;
- ``docker network disconnect`` of the worker that runs an actor, mid-run, for 30 s, then
  ``docker network connect``: the run completes its budget, the replay table holds no
  item twice, and the items acted a stated time after the reconnect are no staler than
  those acted before the cut;
- ``docker kill`` of the worker that runs an actor, mid-run: the run completes on the other
  worker and counts the restarts;
- a container on a network of its own, not the cluster's, reaches none of the head's ports;
- ``graft train --address ray://HEAD:10001 ...`` from a fourth container, not a Ray node;
- the same from a container without the token: refused in one line.

`make test-containers` runs them (marked ``container``: `make test` does not) on the image
$GRAFT_IMAGE (default graft:latest), which must exist; .ci/containers.sh starts dockerd,
builds the image and removes what it made. Everything this module makes is labelled
$GRAFT_CONTAINER_LABEL (default ``graft.test=<pid>``) and removed even when a test fails: the
containers, then the network.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

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

DOCKER = os.environ.get("DOCKER", "docker")
IMAGE = os.environ.get("GRAFT_IMAGE", "graft:latest")
START_LIMIT_S = 600.0
"""Only a guard against a hang: how long the containers and Ray's start may take."""
DOCKER_LIMIT_S = 120.0
"""Only a guard against a hang: one docker command (run, exec, kill, rm)."""


def _in_containers(test: Callable[..., None]) -> Callable[..., None]:
    """Marks a test that needs docker and the image: `make test-containers` runs it."""
    for mark in (pytest.mark.container, pytest.mark.service, pytest.mark.slow):
        test = mark(test)
    return pytest.mark.timeout(START_LIMIT_S + RUN_LIMIT_S + 120)(test)


# deploy/README.md's container walk-through. The README fills the fields with its own
# names and addresses (README_NAMES), the test with its own; the test adds only labels, a
# longer agent start-up wait and tiny budgets.
NETWORK_CMD = "docker network create --subnet {subnet} {network}"
TOKEN = "-v {token}:/etc/ray-token:ro -e RAY_AUTH_TOKEN_PATH=/etc/ray-token/auth_token"
NODE = "docker run -d --init --name {name} --network {network} --ip {ip} --shm-size=1g " + TOKEN
HEAD_CONTAINER = NODE + " -v {runs}:/home/graft/runs {image} sleep infinity"
WORKER_CONTAINER = NODE + " {image} sleep infinity"
ON_NODE = "docker exec -w /opt/graft/src {name} "
"""Before ray-node.sh's commands: the image holds deploy/ at /opt/graft/src."""
IN_HEAD = "docker exec {name} "
"""Before graft train's commands: in the head container's home folder (/home/graft)."""
KILL_CMD = "docker kill {name}"
DISCONNECT_CMD = "docker network disconnect {network} {name}"
CONNECT_CMD = "docker network connect --ip {ip} {network} {name}"
PARTITION_RUN_STEPS = 30000
"""The partitioned run's budget: long enough to go on past the stated recovery time."""
STEPS_PER_INSERT = 8 * 4
"""Steps in one insert batch of pendulum-td3 (steps_per_insert × envs_per_actor)."""
PARTITION_S = 30.0
"""How long a worker is cut off from the cluster's network, mid-run."""
LAG_BACK_S = 60.0
"""The stated recovery: from this long after the reconnect on, the steps acted are on
average at most one version staler than before the cut."""
OUTSIDE_NETWORK_CMD = "docker network create --subnet {outside_subnet} {outside}"
OUTSIDE_CMD = "docker run --rm --network {outside} {image} "
"""Before the probe: a container that is not part of the cluster, on a network of its own."""
PROBE = """
import json, socket, sys
def reached(port):
    try:
        socket.create_connection((sys.argv[1], int(port)), timeout=3).close()
        return True
    except OSError:
        return False
print(json.dumps({port: reached(port) for port in sys.argv[2:]}))
"""
"""python -c PROBE ADDRESS PORT...: which ports of ADDRESS accept a TCP connection."""
CLIENT_CMD = "docker run --rm --name {name} --network {network} --ip {ip} " + TOKEN + " {image} "
NO_TOKEN_CMD = "docker run --rm --network {network} {image} "
"""Before RAY_CLIENT_CMD: a fourth container, with the token and without."""
README_NAMES = {
    "network": "graft-net", "subnet": "10.98.0.0/24", "token": "$HOME/graft-token",
    "runs": "$HOME/graft-runs", "image": "graft:latest", "head": "10.98.0.11",
}  # fmt: skip
README_NODES = {"graft1": "10.98.0.11", "graft2": "10.98.0.12", "graft3": "10.98.0.13"}
README_CLIENT = ("graft4", "10.98.0.14")


def _docker(*args: str, timeout: float = DOCKER_LIMIT_S, check: bool = True) -> str:
    """A docker command's stdout; fails the test in one line if it fails."""
    done = subprocess.run([DOCKER, *args], capture_output=True, text=True, timeout=timeout)
    if check and done.returncode != 0:
        pytest.fail(f"{DOCKER} {' '.join(args[:3])} ...: {done.stderr.strip()}", pytrace=False)
    return done.stdout


class ContainerCluster:
    """Containers on one user-defined bridge network: a head and `workers` workers, each
    running a Ray node, the token mounted read-only; the head's run folders in a folder of
    this machine."""

    def __init__(self, workers: int) -> None:
        pid = os.getpid()
        self.label = os.environ.get("GRAFT_CONTAINER_LABEL") or f"graft.test={pid}"
        prefix = f"10.{150 + pid % 50}.{pid // 50 % 250}"
        # .1 is the network's gateway (the bridge on this machine)
        self.ips = {f"graft-{pid}-{i}": f"{prefix}.{10 + i}" for i in range(1, workers + 3)}
        *nodes, self.client = self.ips
        self.head_node, *self.worker_nodes = nodes
        self.head_ip = self.ips[self.head_node]
        self.folder = Path(tempfile.mkdtemp(prefix="graft-containers-"))
        self.runs = self.folder / "runs"
        """The head's ~/runs: its runs' folders, ray:// ones too."""
        self.names = {
            "network": f"graft-net-{pid}", "subnet": f"{prefix}.0/24",
            "token": str(self.folder / "token"), "runs": str(self.runs), "image": IMAGE,
            "head": self.head_ip, "outside": f"graft-out-{pid}",
            "outside_subnet": f"10.{200 + pid % 50}.{pid // 50 % 250}.0/24",
        }  # fmt: skip

    def docker(self, template: str, *after: str, **fields: str) -> list[str]:
        """A README command at this cluster's names: `docker` as $DOCKER, this module's
        label (and a longer agent start-up wait) on `docker run`, `after` appended."""
        argv = command(template, **(self.names | fields))
        assert argv[0] == "docker", argv
        argv[0] = DOCKER
        if argv[1] == "run":
            # A raylet gives its agents 30 s to start by default; on a machine loaded by
            # other jobs their Python start-up takes longer.
            ours = ["--label", self.label, "-e", "RAY_agent_register_timeout_ms=180000"]
            argv[2:2] = ours
        elif argv[1:3] == ["network", "create"]:
            argv[3:3] = ["--label", self.label]
        return [*argv, *after]

    def start(self) -> None:
        """The token, the network, the containers, then Ray on each (README's commands)."""
        if shutil.which(DOCKER) is None:
            pytest.fail(f"no docker client {DOCKER!r} (set DOCKER)", pytrace=False)
        if _docker("image", "inspect", IMAGE, check=False) == "":
            pytest.fail(f"no image {IMAGE}: build it first (make image)", pytrace=False)
        token = Path(self.names["token"])
        token.mkdir(mode=0o700)
        (token / "auth_token").write_text(secrets.token_hex(32))
        (token / "auth_token").chmod(0o600)
        self.runs.mkdir()
        if os.geteuid() == 0:  # the image's user (graft, uid 1000) reads and writes them
            for made in (token, token / "auth_token", self.runs):
                os.chown(made, 1000, 1000)
        _docker(*self.docker(NETWORK_CMD)[1:])
        _docker(*self.docker(HEAD_CONTAINER, name=self.head_node, ip=self.head_ip)[1:])
        for name in self.worker_nodes:
            _docker(*self.docker(WORKER_CONTAINER, name=name, ip=self.ips[name])[1:])
        self._ray(self.head_node, command(HEAD_CMD, head=self.head_ip))
        for name in self.worker_nodes:
            self._ray(name, command(WORKER_CMD, head=self.head_ip, worker=self.ips[name]))

    def _ray(self, name: str, node_cmd: list[str], attempts: int = 3) -> None:
        """deploy/ray-node.sh in container `name`; again if Ray's fixed 30 s wait for its
        raylet ran out on a loaded machine."""
        argv = self.docker(ON_NODE, *node_cmd, name=name)
        for attempt in range(attempts):
            done = subprocess.run(
                argv, capture_output=True, text=True, timeout=START_LIMIT_S / attempts
            )
            if done.returncode == 0:
                return
            out = done.stdout + done.stderr
            assert "timed out during startup" in out and attempt < attempts - 1, out
            _docker("exec", name, "ray", "stop", "--force", check=False)

    def run(self, argv: list[str]) -> Run:
        """A command (`docker ...`) that runs `graft train`, watched."""
        pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True}
        return Run(lambda: subprocess.Popen(argv, **pipes))

    def find(self, node: str, text: str) -> list[int]:
        """Pids (in its container) of container `node`'s processes whose command line
        contains `text`."""
        rows = _docker("exec", node, "ps", "-eo", "pid=,args=").splitlines()
        return [int(row.split(None, 1)[0]) for row in rows if text in row]

    def env_actors(self) -> int:
        """How many env actors run on the workers."""
        return sum(len(self.find(node, "ray::EnvActor")) for node in self.worker_nodes)

    def listening(self, node: str) -> dict[int, list[str]]:
        """The TCP addresses each process of container `node` listens on, by pid."""
        found: dict[int, list[str]] = {}
        for line in _docker("exec", node, "ss", "-Hltnp").splitlines():
            for pid in re.findall(r"pid=(\d+)", line):
                found.setdefault(int(pid), []).append(line.split()[3])
        return found

    def rejoin(self, name: str) -> bool:
        """Starts Ray on worker `name` again if its raylet ended (Ray declared the node dead
        while it was cut off, and a dead node does not come back by itself); whether it had."""
        if self.find(name, "raylet"):
            return False
        _docker("exec", name, "ray", "stop", "--force", check=False)
        self._ray(name, command(WORKER_CMD, head=self.head_ip, worker=self.ips[name]))
        return True

    def tear_down(self) -> None:
        """Every container and the network this module made (by label), its folder."""
        made = _docker("ps", "-aq", "--filter", f"label={self.label}", check=False).split()
        if made:
            _docker("rm", "-f", *made, check=False)
        _docker("network", "rm", self.names["network"], self.names["outside"], check=False)
        shutil.rmtree(self.folder, ignore_errors=True)


def _graft_argv(template: str, cluster: ContainerCluster) -> list[str]:
    return [*command(template, head=cluster.head_ip), "--no-progress"]


def _train(template: str, cluster: ContainerCluster, *tiny: str) -> list[str]:
    """`graft train` in the head container: the README's command and tiny budgets."""
    train = _graft_argv(template, cluster)
    return cluster.docker(IN_HEAD, *train, *tiny, name=cluster.head_node)


def _small_pendulum(
    cluster: ContainerCluster, run_dir: str, env_steps: int, learning_starts: int
) -> list[str]:
    """`graft train` of pendulum-td3 on the workers with small networks and no evaluation
    until the end, for `env_steps`."""
    return _train(
        PENDULUM_CMD, cluster, "--run-dir", run_dir, "--env-steps", str(env_steps),
        "--set", f"learning_starts={learning_starts}", "--set", "eval_every=100000",
        "--set", "eval_episodes=1", "--set", "td3.hidden_sizes=[16, 16]",
        "--set", "td3.batch_size=32",
    )  # fmt: skip


@pytest.fixture(scope="module")
def cluster():
    made = ContainerCluster(workers=2)
    try:
        made.start()
        yield made
    finally:
        made.tear_down()


def test_the_readme_shows_the_commands_this_module_runs():
    (head, head_ip), *workers = README_NODES.items()
    on_head = {**README_NAMES, "name": head, "ip": head_ip}
    expected = [NETWORK_CMD.format(**README_NAMES), HEAD_CONTAINER.format(**on_head)]
    expected += [IN_HEAD.format(name=head) + c.format(**README_NAMES) for c in CLUSTER_CMDS[2:4]]
    expected += [ON_NODE.format(name=head) + HEAD_CMD.format(**README_NAMES)]
    for name, ip in workers:
        expected.append(WORKER_CONTAINER.format(**README_NAMES, name=name, ip=ip))
        expected.append(ON_NODE.format(name=name) + WORKER_CMD.format(head=head_ip, worker=ip))
    name, ip = README_CLIENT
    client = (CLIENT_CMD + RAY_CLIENT_CMD).format(**README_NAMES, name=name, ip=ip)
    expected += [client, (NO_TOKEN_CMD + RAY_CLIENT_CMD).format(**README_NAMES)]
    name, ip = workers[0]
    expected.append(DISCONNECT_CMD.format(**README_NAMES, name=name))
    expected.append(CONNECT_CMD.format(**README_NAMES, name=name, ip=ip))
    expected.append(KILL_CMD.format(name=name))
    assert readme_lacks(expected) == []


@_in_containers
def test_pendulum_on_the_workers_through_the_label_selector(cluster):
    argv = _train(PENDULUM_CMD, cluster, "--run-dir", "runs/pendulum", *PENDULUM_TINY)
    train = cluster.run(argv)
    metrics = cluster.runs / "pendulum" / "metrics.csv"
    try:
        train.wait_for(lambda: training(metrics), "start training")
        actors_on_workers(cluster)
    finally:
        _, err = train.finish()
    assert train.process.returncode == 0, err
    summary = json.loads((cluster.runs / "pendulum" / "summary.json").read_text())
    assert summary["updates"] == 1000 - 200


@_in_containers
def test_minecraft_worlds_run_inside_the_worker_containers(cluster):
    argv = _train(MINECRAFT_CMD, cluster, "--run-dir", "runs/minecraft", *MINECRAFT_TINY)
    train = cluster.run(argv)
    run_dir = cluster.runs / "minecraft"
    try:
        train.wait_for(lambda: training(run_dir / "metrics.csv"), "start training")
        worlds_beside_their_actors(cluster, actors_on_workers(cluster))
    finally:
        _, err = train.finish()
    assert train.process.returncode == 0, err
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == MINECRAFT_UPDATES


def _stored_items(run_dir: Path) -> dict[str, np.ndarray]:
    """The transitions table of the replay server's last checkpoint (written when the run
    stopped it), its columns by name, with ``inserts`` the items it acknowledged."""
    folder = run_dir / "replay"
    newest = durability.checkpoint_path(folder, durability.checkpoint_numbers(folder)[-1])
    table = durability.read_checkpoint(newest).tables["transitions"]
    items = len(table["keys"])
    columns = {k[4:]: v.reshape(items, -1) for k, v in table.items() if k.startswith("col/")}
    return columns | {"inserts": np.asarray(table["meta"]["inserts"])}


def _staleness(stored: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Each item's acted time and how many versions its weights were behind the newest any
    actor acted with by then (warm-up items left out), in acting order."""
    acted_at, version = stored["acted_at"].ravel(), stored["policy_version"].ravel()
    keep = version >= 0
    order = np.argsort(acted_at[keep], kind="stable")
    acted_at, version = acted_at[keep][order], version[keep][order]
    return acted_at, np.maximum.accumulate(version) - version


@_in_containers
def test_a_worker_cut_off_for_30_s_mid_run_and_reconnected(cluster):
    env_steps, learning_starts = PARTITION_RUN_STEPS, 200
    train = cluster.run(_small_pendulum(cluster, "runs/partition", env_steps, learning_starts))
    run_dir = cluster.runs / "partition"
    try:
        train.wait_for(lambda: training(run_dir / "metrics.csv"), "start training")
        started = time.time()
        cut = next(iter(actors_on_workers(cluster).values()))
        train.wait_for(lambda: time.time() > started + 10, "run for 10 s")
        cut_at = time.time()
        _docker(*cluster.docker(DISCONNECT_CMD, name=cut)[1:])
        time.sleep(PARTITION_S)
        _docker(*cluster.docker(CONNECT_CMD, name=cut, ip=cluster.ips[cut])[1:])
        back_at = time.time()
    finally:
        _, err = train.finish()
    ended = time.time()
    rejoined = cluster.rejoin(cut)  # for the tests after this one
    assert train.process.returncode == 0, err
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["updates"] == env_steps - learning_starts  # the learner's whole budget
    assert summary["env_steps"] == env_steps

    stored = _stored_items(run_dir)
    rows = np.concatenate([stored[c] for c in ("obs", "action", "next_obs")], axis=1)
    assert len(np.unique(rows, axis=0)) == len(rows)  # no step stored twice
    # A replaced actor's last batch in flight and the one it had claimed go back to the
    # budget; the actor, back before Ray ended it, may still store them.
    restarts = metric(run_dir / "metrics.csv", "faults/actor_restarts")[-1]
    assert 0 <= len(rows) - env_steps <= 2 * restarts * STEPS_PER_INSERT, (len(rows), restarts)

    acted_at, behind = _staleness(stored)
    before, after = behind[acted_at < cut_at], behind[acted_at >= back_at + LAG_BACK_S]
    first_back = acted_at[acted_at >= back_at].min() - back_at
    print(
        f"cut off {PARTITION_S:.0f} s, {cut_at - started:.0f} s into training; first step "
        f"acted {first_back:.0f} s after the reconnect; run ended {ended - back_at:.0f} s after "
        f"it; {len(rows)} steps stored for {env_steps}; actor restarts {restarts:.0f}; raylet "
        f"started again: {rejoined}; versions behind, mean (max): before the cut "
        f"{before.mean():.2f} ({before.max()}), from {LAG_BACK_S:.0f} s after the reconnect "
        f"{after.mean():.2f} ({after.max() if len(after) else '-'})"
    )
    assert len(after) > 0, "the run ended too soon after the reconnect"
    assert after.mean() <= before.mean() + 1.0


@_in_containers
def test_the_heads_ports_are_unreachable_from_outside_the_clusters_network(cluster):
    listens = [a for found in cluster.listening(cluster.head_node).values() for a in found]
    # Every port the head listens on beyond its loopback, and the dashboard's (off).
    ports = {a.rsplit(":", 1)[1] for a in listens if not a.startswith(("127.", "[::1]"))}
    assert "6379" in ports, listens  # the GCS
    probe = ["python", "-c", PROBE, cluster.head_ip, *sorted(ports | {"8265"})]
    client = cluster.docker(CLIENT_CMD, name=cluster.client, ip=cluster.ips[cluster.client])
    inside = json.loads(_docker(*client[1:], *probe))
    assert inside["6379"] and inside["10001"], inside  # what a cluster member reaches
    _docker(*cluster.docker(OUTSIDE_NETWORK_CMD)[1:])
    outside = json.loads(_docker(*cluster.docker(OUTSIDE_CMD)[1:], *probe))
    assert [p for p, reached in outside.items() if reached] == [], outside


@_in_containers
def test_a_run_completes_on_the_other_worker_when_one_is_killed(cluster):
    env_steps, learning_starts = 3000, 200
    train = cluster.run(_small_pendulum(cluster, "runs/killed", env_steps, learning_starts))
    metrics = cluster.runs / "killed" / "metrics.csv"
    try:
        # Early in the run: as soon as both actors run on the workers.
        train.wait_for(lambda: cluster.env_actors() >= 2, "place its actors")
        killed = next(iter(actors_on_workers(cluster).values()))
        _docker(*cluster.docker(KILL_CMD, name=killed)[1:])
        cluster.worker_nodes.remove(killed)
    finally:
        _, err = train.finish()
    assert train.process.returncode == 0, err
    assert "env actor" in err and "restarted it" in err, err
    restarts = metric(metrics, "faults/actor_restarts")[-1]
    assert restarts >= 1
    summary = json.loads((cluster.runs / "killed" / "summary.json").read_text())
    assert summary["updates"] == env_steps - learning_starts  # the learner's whole budget
    assert summary["env_steps"] == env_steps


@_in_containers
def test_a_ray_client_in_a_fourth_container_runs_in_the_cluster(cluster):
    # No --run-dir: the run's default folder, under the home folder of the head's Ray.
    client = cluster.docker(CLIENT_CMD, name=cluster.client, ip=cluster.ips[cluster.client])
    train = cluster.run([*client, *_graft_argv(RAY_CLIENT_CMD, cluster), *PENDULUM_TINY])
    try:
        train.wait_for(
            lambda: cluster.find(cluster.head_node, "/home/graft/runs/"),
            "start a replay server on the head",
        )
        (replay,) = cluster.find(cluster.head_node, "/home/graft/runs/")
        assert cluster.find(cluster.head_node, REPLAY_SERVER) == [replay]
        # The fourth container runs only `graft train` (a Ray Client): no replay server,
        # no Ray node.
        for text in (REPLAY_SERVER, "ray::", "raylet", "gcs_server"):
            assert cluster.find(cluster.client, text) == [], text
    finally:
        out, err = train.finish()
    assert train.process.returncode == 0, err
    said = re.search(f"the run ran on {re.escape(cluster.head_ip)}; its folder is there: (.+)", out)
    assert said is not None, out
    run_dir = Path(said[1])
    assert run_dir.parent == Path("/home/graft/runs"), run_dir
    assert run_dir.name.startswith("pendulum-td3-s0-"), run_dir
    summary = json.loads((cluster.runs / run_dir.name / "summary.json").read_text())
    assert summary["updates"] == 1000 - 200


@_in_containers
def test_a_container_without_the_token_is_refused_in_one_line(cluster):
    no_token = cluster.docker(NO_TOKEN_CMD)
    argv = [*no_token, *_graft_argv(RAY_CLIENT_CMD, cluster), "--run-dir", "runs/refused"]
    train = cluster.run(argv)
    _, err = train.finish()
    assert train.process.returncode == 2, err
    one_line_refusal(
        err,
        f"--address ray://{cluster.head_ip}:10001: Ray Client could not connect",
        "the cluster's token in ~/.ray/auth_token",
    )
