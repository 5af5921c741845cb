"""Runs a training run inside a Ray cluster reached through Ray Client (``ray://HOST:10001``).

Through Ray Client this process is outside the cluster: a replay server started here would
listen behind the client machine's loopback or firewall, where the actors cannot reach it.
So the whole run (learner, replay server, supervision) runs as one Ray task on the head
node (or where the preset's ``learner`` section places it) with ``address='auto'``, exactly
as `graft train --address auto` would run there (`driver.train_here`); this process waits
for its result. The run folder is written on that node.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Optional

import ray
from ray.exceptions import AuthenticationError, RayTaskError

from graft.config import TrainConfig
from graft.orchestration.driver import RunResult, train_here
from graft.orchestration.preflight import default_run_dir
from graft.orchestration.ray_session import connect_ray
from graft.placement import LearnerPlacement, check_placement, cluster_nodes
from graft.validation import ConfigError

HEAD_NODE = "node:__internal_head__"
"""The resource only Ray's head node carries."""


def learner_options(placement: LearnerPlacement) -> dict[str, Any]:
    """The learner task's Ray options: the preset's, pinned to the head node when the
    preset names neither resources nor labels for it."""
    options = placement.ray_options()
    if not placement.resources and not placement.label_selector:
        options["resources"] = {HEAD_NODE: 0.001}
    return options


def _run_there(
    config: TrainConfig, run_dir: Optional[str], resume: bool, address: str
) -> tuple[RunResult, str]:
    """The Ray task: the run, on the node Ray placed it, joined to its cluster."""
    folder = Path(run_dir).expanduser() if run_dir else default_run_dir(config)
    if not folder.is_absolute():
        folder = Path.home() / folder  # a Ray worker's working folder is Ray's own
    result = train_here(config, address="auto", run_dir=folder, resume=resume, progress=False)
    return result, ray.util.get_node_ip_address()


def _unreachable(address: str, error: Exception) -> str:
    """One line for a Ray Client that found no server, or one that refused its token."""
    token = os.environ.get("RAY_AUTH_TOKEN_PATH") or "~/.ray/auth_token"
    why = (str(error).strip().splitlines() or [type(error).__name__])[0]
    return (
        f"--address {address}: Ray Client could not connect ({why}); the head must run "
        "Ray Client's server on that port (`ray start --head` opens 10001), and on a "
        f"cluster with token auth this machine needs the cluster's token in {token} "
        "(deploy/ray-node.sh copy-token USER@THIS_MACHINE)"
    )


def train_on_cluster(
    config: TrainConfig, *, address: str, run_dir: Optional[Path], resume: bool
) -> RunResult:
    """Runs `config` as a Ray task in the cluster at `address` (``ray://...``).

    Raises:
        ConfigError: no Ray Client server at `address` takes this machine (none there,
            or no or a wrong token), the learner cannot be placed, or the run refuses a
            value there.
    """
    for attempt in range(2):
        try:
            connect_ray(address)
            break
        except (ConnectionError, AuthenticationError) as error:
            # AuthenticationError: token auth is on (RAY_AUTH_MODE=token) but no token here.
            if attempt == 0 and "Initialization failure" in str(error):
                # The server took the connection but the session process it starts for
                # this client did not come up in time (a loaded head): once more.
                print(
                    f"--address {address}: Ray Client's session did not start there; "
                    "trying once more",
                    file=sys.stderr,
                    flush=True,
                )
                ray.shutdown()
                continue
            raise ConfigError(_unreachable(address, error)) from None
    try:
        options = learner_options(config.learner)
        placed = LearnerPlacement(
            num_cpus=options["num_cpus"],
            num_gpus=options["num_gpus"],
            resources=options["resources"],
            label_selector=options.get("label_selector", {}),
        )
        problem = check_placement(
            [("learner", placed, 1)], cluster_nodes(), where=f"the Ray cluster at {address}"
        )
        if problem is not None:
            raise ConfigError(problem)
        task = ray.remote(_run_there).options(**options)
        ref = task.remote(config, str(run_dir) if run_dir else None, resume, address)
        try:
            result, node = ray.get(ref)
        except KeyboardInterrupt:  # Ctrl-C here stops the run there, which saves and stops
            ray.cancel(ref)
            result, node = ray.get(ref)
        except RayTaskError as error:
            if isinstance(error.cause, ConfigError):
                raise ConfigError(str(error.cause)) from None
            raise
        print(f"the run ran on {node}; its folder is there: {result.run_dir}")
        return result
    finally:
        ray.shutdown()
