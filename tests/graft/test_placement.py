"""Placement: the preset's per-role resources, refused in one line when they cannot be placed."""

from __future__ import annotations

import pytest

from graft.config import load_preset
from graft.placement import ActorPlacement, Node, Placement, check_placement
from graft.validation import ConfigError

TWO_CPUS = [Node("10.0.0.2", {"CPU": 2.0})]


def test_placement_reaches_ray_options() -> None:
    config = load_preset(
        "pendulum-td3",
        **{"actors.num_cpus": 0.5, "actors.resources": {"minecraft": 1},
           "actors.label_selector": {"zone": "a"}},
    )  # fmt: skip
    assert config.actors.ray_options() == {
        "num_cpus": 0.5,
        "num_gpus": 0.0,
        "resources": {"minecraft": 1},
        "label_selector": {"zone": "a"},
    }
    assert config.actors.demand() == {"CPU": 0.5, "minecraft": 1.0}


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("actors.num_cpus", -1, "actors.num_cpus=-1 must be a number >= 0"),
        ("actors.resources", {"gpu-ish": "lots"}, "actors.resources={'gpu-ish': 'lots'} must map"),
        ("evaluator.max_restarts", -2, "evaluator.max_restarts=-2 must be >= 0"),
        ("replay.port", 70000, "replay.port=70000 must lie in [0, 65535]"),
    ],
)
def test_bad_placement_values_are_refused_in_one_line(key, value, message) -> None:
    with pytest.raises(ConfigError) as caught:
        load_preset("pendulum-td3", **{key: value})
    assert str(caught.value).startswith(message)


def test_actors_that_fit_pass() -> None:
    roles = [("evaluator", ActorPlacement(), 1), ("actors", ActorPlacement(), 7)]
    assert check_placement(roles, TWO_CPUS, where="the cluster") is None


def test_too_many_actors_name_how_many_fit_and_the_fix() -> None:
    roles = [("evaluator", ActorPlacement(), 1), ("actors", ActorPlacement(), 12)]
    assert check_placement(roles, TWO_CPUS, where="the local Ray instance") == (
        "actors: 12 × (0.25 CPU) do not fit the local Ray instance (2 CPU on 1 eligible "
        "node(s)); only 7 fit. Use --actors 7, lower actors.num_cpus (--set "
        "actors.num_cpus=...), or add nodes"
    )


def test_an_actor_larger_than_any_node_is_refused() -> None:
    # 3 CPUs in total, but no single node holds 2.
    nodes = [Node("a", {"CPU": 1.5}), Node("b", {"CPU": 1.5})]
    problem = check_placement([("actors", Placement(num_cpus=2), 1)], nodes, where="the cluster")
    assert problem is not None and "only 0 fit. Use a node with 2 CPU" in problem


def test_a_missing_custom_resource_is_named() -> None:
    roles = [("actors", Placement(resources={"minecraft": 1}), 2)]
    problem = check_placement(roles, TWO_CPUS, where="the cluster")
    assert problem is not None and "(0 minecraft on 1 eligible node(s))" in problem
    assert "actors.resources.minecraft" in problem


def test_a_label_selector_matching_no_node_is_refused() -> None:
    nodes = [Node("head", {"CPU": 0.0}), Node("w", {"CPU": 2.0}, {"graft-node": "worker"})]
    ok = [("actors", Placement(label_selector={"graft-node": "worker"}), 4)]
    assert check_placement(ok, nodes, where="the cluster") is None
    wrong = [("actors", Placement(label_selector={"graft-node": "gpu"}), 1)]
    assert check_placement(wrong, nodes, where="the cluster") == (
        "actors.label_selector={'graft-node': 'gpu'} matches no node of the cluster; start "
        "nodes with `ray start --labels graft-node=gpu` or change the selector"
    )
