"""What the multi-node tests share: deploy/README.md's commands, a run they watch, and the
checks of where a run's actors ran.

Two clusters tell the same story: Ray nodes in network namespaces (test_multinode.py) and
in containers of deploy/Dockerfile's image (test_containers.py). Each runs the README's
commands at its own addresses, behind its own prefix (``ip netns exec NS``, ``docker exec
NAME``), so both walk-throughs and both tests use the templates below.
"""

from __future__ import annotations

import csv
import re
import shlex
import subprocess
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Protocol

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "deploy" / "README.md"
RUN_LIMIT_S = 600.0
"""Only a guard against a hang: how long one run may take on a loaded machine."""
REPLAY_SERVER = "graft.cli.replay serve"
"""What the replay server's command line holds."""

# The commands of deploy/README.md's walk-throughs, with {head}, {worker} and {client} for
# the addresses. The tests add only tiny budgets (and a temp folder / run folder).
HEAD_CMD = "deploy/ray-node.sh head --ip {head} --num-cpus 0"
WORKER_CMD = (
    "deploy/ray-node.sh worker --head {head}:6379 --ip {worker} --num-cpus 2 "
    "--labels graft-node=worker"
)
ON_WORKERS = "--set 'actors.label_selector={{graft-node: worker}}'"
PENDULUM_CMD = f"graft train --preset pendulum-td3 --address {{head}}:6379 --actors 2 {ON_WORKERS}"
MINECRAFT_CMD = (
    f"graft train --preset minecraft-backbone --address {{head}}:6379 --clients 2 {ON_WORKERS}"
)
RAY_CLIENT_CMD = (
    f"graft train --preset pendulum-td3 --address ray://{{head}}:10001 --actors 2 {ON_WORKERS}"
)
CLUSTER_CMDS = (HEAD_CMD, WORKER_CMD, PENDULUM_CMD, MINECRAFT_CMD, RAY_CLIENT_CMD)

PENDULUM_TINY = [
    "--env-steps", "1000", "--set", "learning_starts=200", "--set", "eval_every=100000",
    "--set", "eval_episodes=1", "--set", "td3.hidden_sizes=[16, 16]",
    "--set", "td3.batch_size=32",
]  # fmt: skip
MINECRAFT_TINY = [
    "--env-steps", "1200", "--set", "learning_starts=200", "--set", "slack_env_steps=64",
    "--set", "steps_per_insert=16", "--set", "publish_every=20",
    "--set", "eval_every=100000", "--set", "eval_episodes=1", "--set", "checkpoint_every=100000",
    "--set", "td3.hidden_sizes=[32, 32]", "--set", "td3.batch_size=32",
    "--set", "env_kwargs.ticks_per_step=2",
]  # fmt: skip
MINECRAFT_UPDATES = int((1200 - 200) * 0.5)
"""The tiny run's update budget: (env_steps - learning_starts) × updates_per_env_step."""


def command(template: str, **addresses: str) -> list[str]:
    """One of the README's commands, as argv, at the given addresses."""
    return shlex.split(template.format(**addresses))


def readme_lacks(commands: Iterable[str]) -> list[str]:
    """The `commands` deploy/README.md does not show, its lines joined where they end in a
    backslash and runs of spaces made one."""
    text = README.read_text().replace("\\\n", " ")
    text = re.sub(r"[ \t]+", " ", re.sub(r"\.venv/bin/|\$PWD/", "", text))
    return [c for c in commands if c not in text]


def metric(csv_path: Path, key: str) -> list[float]:
    """Every value of `key` in a run's metrics.csv, in order."""
    with csv_path.open() as f:
        return [float(row["value"]) for row in csv.DictReader(f) if row["key"] == key]


def training(metrics: Path) -> bool:
    """The learner trains: its first metrics rows are written."""
    return metrics.exists() and len(metrics.read_text().splitlines()) > 4


class Run:
    """A `graft train` started by `popen` (stdout and stderr piped, text), its output
    collected when it ends."""

    def __init__(self, popen: Callable[[], subprocess.Popen], limit_s: float = RUN_LIMIT_S):
        self.process = popen()
        self.deadline = time.monotonic() + limit_s
        self.out, self.err = "", ""

    def wait_for(self, ready: Callable[[], object], what: str) -> None:
        """Polls `ready()` until it is true; fails if the run ends or takes too long first."""
        while not ready():
            assert self.process.poll() is None, self.finish()
            assert time.monotonic() < self.deadline, f"the run did not {what}"
            time.sleep(0.5)

    def finish(self) -> tuple[str, str]:
        """Waits for the run to end (kills it past the deadline); its stdout and stderr."""
        try:
            self.out, self.err = self.process.communicate(
                timeout=max(self.deadline - time.monotonic(), 1)
            )
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.out, self.err = self.process.communicate()
        return self.out, self.err


class Nodes(Protocol):
    """A cluster's nodes as the checks see them: names, and the processes on each."""

    head_node: str
    worker_nodes: list[str]

    def find(self, node: str, text: str) -> list[int]:
        """Pids on `node` whose command line contains `text`."""
        ...

    def listening(self, node: str) -> dict[int, list[str]]:
        """The TCP addresses each process of `node` listens on, by pid."""
        ...


def actors_on_workers(nodes: Nodes) -> dict[int, str]:
    """The run's two env actors, pid -> worker node; none may run on the head."""
    assert nodes.find(nodes.head_node, "ray::EnvActor") == [], "an actor ran on the 0-CPU head"
    on_workers = {p: n for n in nodes.worker_nodes for p in nodes.find(n, "ray::EnvActor")}
    assert len(on_workers) == 2, on_workers
    return on_workers


def worlds_beside_their_actors(nodes: Nodes, on_workers: dict[int, str]) -> None:
    """Each Minecraft actor serves its own simulated world on its node's loopback."""
    for pid, node in on_workers.items():
        listens = nodes.listening(node).get(pid, [])
        assert any(a.startswith("127.0.0.1:") for a in listens), (pid, node, listens)


def one_line_refusal(err: str, *parts: str) -> str:
    """The one `graft train:` line of a refused run's stderr, holding every one of `parts`;
    no traceback."""
    assert "Traceback" not in err, err
    (line,) = [line for line in err.splitlines() if line.startswith("graft train:")]
    for part in parts:
        assert part in line, (part, line)
    return line
