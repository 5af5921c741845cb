"""Where each role of a run is placed and what it reserves: the preset's ``actors``,
``evaluator``, ``learner`` and ``replay`` sections, and the check that the run's Ray
actors can be placed on the cluster before any of them starts.

    actors:    {num_cpus: 0.25, resources: {minecraft: 1}, label_selector: {zone: gpu-a}}
    evaluator: {num_cpus: 0.25}
    learner:   {num_gpus: 1, device: cuda}  # the learner's Ray task (ray:// runs), its device
    replay:    {port: 9100, shards: 2}  # the servers' first port, fixed for firewalls

A role that cannot be placed would wait forever for a node (Ray keeps such actors
pending without a word), so `check_placement` refuses the run in one line that names
what is missing and how to fix it.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Optional

from learner.device_spec import check_compile_mode, check_device_spec


@dataclass(frozen=True)
class Placement:
    """What one Ray-placed role reserves, and on which nodes it may run."""

    num_cpus: float = 0.25
    """CPUs reserved per process of the role (Ray's bookkeeping; a process may use more)."""
    num_gpus: float = 0.0
    """GPUs reserved per process of the role."""
    resources: dict[str, float] = field(default_factory=dict)
    """Custom resources per process, e.g. ``{minecraft: 1}`` for nodes started with
    ``ray start --resources '{"minecraft": 4}'``."""
    label_selector: dict[str, str] = field(default_factory=dict)
    """Node labels the role's nodes must carry (``ray start --labels zone=a``)."""

    def __post_init__(self) -> None:
        for name in ("num_cpus", "num_gpus"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or value < 0 or math.isnan(value):
                raise ValueError(f"{name}={value!r} must be a number >= 0")
        if not isinstance(self.resources, dict) or not all(
            isinstance(k, str) and isinstance(v, (int, float)) and v >= 0
            for k, v in self.resources.items()
        ):
            raise ValueError(
                f"resources={self.resources!r} must map resource names to amounts >= 0"
            )
        if not isinstance(self.label_selector, dict) or not all(
            isinstance(k, str) and isinstance(v, str) for k, v in self.label_selector.items()
        ):
            raise ValueError(
                f"label_selector={self.label_selector!r} must map label names to values"
            )

    def demand(self) -> dict[str, float]:
        """The Ray resources one process of the role reserves."""
        wanted = {"CPU": float(self.num_cpus), "GPU": float(self.num_gpus), **self.resources}
        return {k: float(v) for k, v in wanted.items() if v > 0}

    def ray_options(self) -> dict[str, Any]:
        """Keyword arguments of a Ray actor's or task's ``.options(...)``."""
        options: dict[str, Any] = {
            "num_cpus": self.num_cpus,
            "num_gpus": self.num_gpus,
            "resources": dict(self.resources),
        }
        if self.label_selector:
            options["label_selector"] = dict(self.label_selector)
        return options


@dataclass(frozen=True)
class ActorPlacement(Placement):
    """A role of Ray actors that are replaced when they die (env actors, the evaluator)."""

    max_restarts: int = 10
    """How often the role's actors may be replaced after dying before the run fails."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.max_restarts < 0:
            raise ValueError(f"max_restarts={self.max_restarts} must be >= 0")


@dataclass(frozen=True)
class LearnerPlacement(Placement):
    """The learner (with the replay server it starts): the `graft train` process itself,
    except for ``ray://`` addresses, where it runs as a Ray task placed by these fields
    (on the head node unless ``resources`` or ``label_selector`` say otherwise)."""

    num_cpus: float = 0.0
    """CPUs the learner's task reserves (0: a head node started with no CPUs takes it)."""
    device: str = "auto"
    """Where the learner computes: auto (CUDA when this process sees a GPU, else the CPU),
    cpu, cuda or cuda:N; a ``ray://`` run's learner sees a GPU only with ``num_gpus: 1``."""
    compile: str = "auto"
    """The update: off (eager), compile (the networks' forward passes by torch.compile),
    cuda_graphs (those replayed as CUDA graphs), captured (the whole update one CUDA graph,
    metrics read per log interval) or auto (captured on CUDA, eager on the CPU)."""
    prefetch_to_device: int = 2
    """Sampled batches copied to a CUDA device ahead of their update (none on the CPU)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_device_spec(self.device)
        check_compile_mode(self.compile)
        if self.prefetch_to_device < 0:
            raise ValueError(f"prefetch_to_device={self.prefetch_to_device} must be >= 0")


@dataclass(frozen=True)
class ReplaySettings:
    """The replay server: a child of the learner's process, restarted from its checkpoint
    folder when it dies."""

    port: int = 0
    """Port the server listens on (0: a free one; fix it where a firewall needs to know)."""
    checkpoint_every_s: float = 30.0
    """Seconds between the server's checkpoints (its log keeps every insert between them)."""
    max_restarts: int = 10
    """How often a server may be restarted after dying before the run fails (per shard)."""
    shards: int = 1
    """Replay servers the run starts (1 to 255): actor i inserts into shard i mod N, the
    learner samples all; shard K listens on ``port + K`` when a port is fixed."""

    def __post_init__(self) -> None:
        if not 0 <= self.port < 65536:
            raise ValueError(f"port={self.port} must lie in [0, 65535] (0: a free port)")
        if not 1 <= self.shards <= 255:
            raise ValueError(f"shards={self.shards} must lie in [1, 255]")
        if self.port and self.port + self.shards - 1 > 65535:
            raise ValueError(
                f"port={self.port} with shards={self.shards}: shard K listens on port + K, "
                "which must stay <= 65535"
            )
        if self.checkpoint_every_s <= 0:
            raise ValueError(f"checkpoint_every_s={self.checkpoint_every_s} must be > 0")
        if self.max_restarts < 0:
            raise ValueError(f"max_restarts={self.max_restarts} must be >= 0")


@dataclass(frozen=True)
class Node:
    """One node as the placement check sees it: its total resources and labels."""

    name: str
    resources: dict[str, float]
    labels: dict[str, str] = field(default_factory=dict)


def local_cpus() -> float:
    """CPUs of the local Ray instance (running, or the one `connect_ray('local')` starts).
    Needs no torch; Ray, if not loaded yet, is imported only to read the CPU quota."""
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        return float(ray.cluster_resources().get("CPU", 0.0))
    try:
        from ray._private.utils import get_num_cpus  # the cgroup quota, as Ray will see it

        return float(get_num_cpus())
    except (ImportError, AttributeError):  # not in this Ray version: the machine's cores
        return float(os.cpu_count() or 1)


def cluster_nodes() -> list[Node]:
    """The alive nodes of the connected Ray cluster."""
    import ray

    return [
        Node(n["NodeManagerAddress"], dict(n["Resources"]), dict(n.get("Labels") or {}))
        for n in ray.nodes()
        if n.get("Alive")
    ]


def check_placement(
    roles: list[tuple[str, Placement, int]], nodes: list[Node], *, where: str
) -> Optional[str]:
    """None when every process of every role fits the nodes, else one line saying what
    is missing and how to fix it.

    Args:
        roles: (section name, placement, processes) in placing order, e.g.
            ``[("evaluator", ..., 1), ("actors", ..., 12)]``.
        nodes: the cluster's nodes with their total resources.
        where: how to name the cluster in the message ("the local Ray instance").
    """
    free = {n.name: dict(n.resources) for n in nodes}
    for section, placement, count in roles:
        eligible = [n for n in nodes if _matches(n.labels, placement.label_selector)]
        if not eligible:
            labels = ", ".join(f"{k}={v}" for k, v in placement.label_selector.items())
            return (
                f"{section}.label_selector={placement.label_selector} matches no node of "
                f"{where}; start nodes with `ray start --labels {labels}` or change the selector"
            )
        need = placement.demand()
        for placed in range(count):
            node = next((n for n in eligible if _fits(need, free[n.name])), None)
            if node is None:
                return _missing(section, placement, count, placed, eligible, where)
            for key, amount in need.items():
                free[node.name][key] -= amount
    return None


def _matches(labels: Mapping[str, str], selector: Mapping[str, str]) -> bool:
    return all(labels.get(k) == v for k, v in selector.items())


def _fits(need: Mapping[str, float], free: Mapping[str, float]) -> bool:
    return all(free.get(k, 0.0) + 1e-9 >= v for k, v in need.items())


def _missing(
    section: str, placement: Placement, count: int, placed: int, nodes: list[Node], where: str
) -> str:
    need = placement.demand()
    total = {k: sum(n.resources.get(k, 0.0) for n in nodes) for k in need}
    short = [k for k in need if total[k] < need[k] * count] or list(need)
    key = short[0]
    each = ", ".join(f"{v:g} {k}" for k, v in need.items())
    field_name = {"CPU": "num_cpus", "GPU": "num_gpus"}.get(key, f"resources.{key}")
    fix = (
        (f"--actors {placed}" if section == "actors" else f"fewer processes of {section}")
        if placed
        else f"a node with {need[key]:g} {key}"
    )
    return (
        f"{section}: {count} × ({each}) do not fit {where} ({total[key]:g} {key} on "
        f"{len(nodes)} eligible node(s)); only {placed} fit. Use {fix}, lower "
        f"{section}.{field_name} (--set {section}.{field_name}=...), or add nodes"
    )
