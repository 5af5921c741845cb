"""Minecraft fleets: each actor and the evaluator play in a world of their own, either a
simulated world each starts itself or a listed Minecraft client; a shared or missing
client is refused in one line before Ray starts."""

from __future__ import annotations

import pytest

from graft.cli import main
from graft.config import load_preset
from graft.orchestration import assembly
from graft.orchestration.clients import actor_env, evaluator_env, world_clients
from graft.orchestration.launcher import train
from minecraft.malmo.client import MalmoClient
from minecraft.sim.pool import ServerPool
from minecraft.sim.timing import IDEAL
from tests.graft.test_travel_service import TINY

TRAIN = ["train", "--preset", "minecraft-backbone", "--actors", "2"]


@pytest.fixture(autouse=True)
def _no_ray_address(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.chdir(tmp_path)


def _refused(argv: list[str], capsys) -> str:
    """The one line `graft argv` printed when it refused, having started no Ray."""

    def no_ray(address: str) -> bool:
        raise AssertionError(f"Ray was started ({address}) before the refusal")

    with pytest.MonkeyPatch.context() as patch, pytest.raises(SystemExit) as exit:
        patch.setattr(assembly, "connect_ray", no_ray)
        main(argv)
    assert exit.value.code == 2
    err = capsys.readouterr().err
    assert err.endswith("\n") and err.count("\n") == 1, err  # one line, no traceback
    return err.rstrip("\n")


REFUSED = {
    "one client shared by two actors": (
        ["--set", "clients=[127.0.0.1:9000, 127.0.0.1:9001, 127.0.0.1:9000]"],
        "clients: 127.0.0.1:9000 is listed twice (entries 0 and 2); a client plays one "
        "mission at a time, so two actors cannot share it",
    ),
    "fewer clients than actors and the evaluator": (
        ["--set", "clients=[127.0.0.1:9000, 127.0.0.1:9001]"],
        "clients: 2 clients for 2 actors and the evaluator; need 3 (or --actors 1)",
    ),
    "not host:port": (
        ["--set", "clients=[127.0.0.1:9000, minecraft, 127.0.0.1:9002]"],
        "clients[1]='minecraft' is not host:port (e.g. 10.0.0.5:9000)",
    ),
    "one address for every actor": (
        ["--set", "env_kwargs.address=127.0.0.1:9000"],
        "env_kwargs.address='127.0.0.1:9000' would put all 2 actors and the evaluator in one "
        "world, each new mission replacing the last; list one client per actor and one for "
        "the evaluator in `clients` (host:port list) or `clients_file`",
    ),
    "fewer clients than the actors' environments": (
        ["--set", "envs_per_actor=2", "--set", "clients=[h:1, h:2, h:3]"],
        "clients: 3 clients for 2 actors x 2 environments and the evaluator; need 5 "
        "(or --actors 1)",
    ),
    "a niceness Linux has not": (
        ["--set", "actor_nice=25"],
        "actor_nice=25 must be within -20..19 (Linux)",
    ),
    "a missing clients file": (
        ["--set", "clients_file=nowhere.txt"],
        "clients_file='nowhere.txt' cannot be read: No such file or directory",
    ),
}


@pytest.mark.parametrize("case", REFUSED, ids=list(REFUSED))
@pytest.mark.service
def test_a_run_refuses_clients_it_cannot_give_each_actor_alone(case, capsys) -> None:
    extra, expected = REFUSED[case]
    assert _refused([*TRAIN, *extra], capsys) == f"graft train: {expected}"


def test_a_clients_file_lists_one_client_a_line_and_each_actor_gets_its_own(tmp_path) -> None:
    listed = tmp_path / "clients.txt"
    listed.write_text(
        "# the lab's clients\n10.0.0.5:9000\n\n10.0.0.6:9000  # spare\n10.0.0.7:9000\n"
    )
    config = load_preset("minecraft-backbone", num_actors=2, clients_file=str(listed))
    clients = world_clients(config)
    assert clients == ["10.0.0.5:9000", "10.0.0.6:9000", "10.0.0.7:9000"]
    addresses = [[e.env_kwargs["address"] for e in actor_env(config, clients, i)] for i in (0, 1)]
    assert addresses == [["10.0.0.5:9000"], ["10.0.0.6:9000"]]
    assert evaluator_env(config, clients).env_kwargs["address"] == "10.0.0.7:9000"
    # Without clients every environment starts its own simulated world: no address.
    plain = load_preset("minecraft-backbone", num_actors=2)
    assert world_clients(plain) == []
    assert "address" not in actor_env(plain, [], 0).env_kwargs


def test_several_environments_of_an_actor_each_play_in_a_client_of_their_own() -> None:
    listed = [f"10.0.0.{i}:9000" for i in range(1, 7)]  # one spare
    config = load_preset("minecraft-backbone", num_actors=2, envs_per_actor=2, clients=listed)
    clients = world_clients(config)
    assert clients == listed[:5]
    envs = [[e.env_kwargs["address"] for e in actor_env(config, clients, i)] for i in (0, 1)]
    assert envs == [listed[0:2], listed[2:4]]
    assert evaluator_env(config, clients).env_kwargs["address"] == listed[4]


@pytest.mark.slow
def test_each_environment_and_the_evaluator_play_in_their_own_listed_client(
    ray_local, tmp_path
) -> None:
    with ServerPool(5, base_port=0, seed=0, timing=IDEAL) as pool:
        clients = [f"127.0.0.1:{port}" for port in pool.ports]
        config = load_preset("minecraft-backbone", **TINY, envs_per_actor=2, clients=clients)
        result = train(config, run_dir=tmp_path / "run", progress=False)
        status = [MalmoClient("127.0.0.1", port).status() for port in pool.ports]
    assert all(n > 0 for n in result.summary["actor_env_steps"])
    # Five players (two actors' two environments each, the evaluator), five clients, each
    # ran missions: so no two players shared one (a shared one would leave another idle).
    assert [s["missions_started"] >= 1 for s in status] == [True] * 5, status
