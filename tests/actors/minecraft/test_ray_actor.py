"""Minecraft clients on Ray, against real processes: a world server (``minecraft serve``),
a replay server (``graft replay serve``) and a local Ray instance. The actor streams
transitions, reports skipped ticks and latency, adopts broadcast weights without waiting,
and reconnects when its world server is killed and restarted."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
import ray
import torch

from actors.minecraft.encoding import (
    ACTION_SPACE,
    action_commands,
    encode_observation,
    observation_space,
)
from actors.minecraft.malmo.mission import parse_mission
from actors.minecraft.malmo.mission_xml import mission_xml
from actors.minecraft.ray_actor import MinecraftActor, MinecraftAgent
from actors.minecraft.sim.pool import ServerPool
from actors.policies import gaussian_log_prob
from actors.transitions import transition_signature
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from service.replay.client import ReplayClient
from service.run.replay_process import ReplayProcess
from service.weights import WeightBroadcaster
from tests.actors.minecraft.conftest import flat_mission

MISSION = flat_mission(grid_radius=1, ms_per_tick=20)
OBS_DIM = 8 + 27
TD3 = TD3Config(hidden_sizes=(32,), batch_size=16)


def wait_for(predicate, timeout: float = 30.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not reached in {timeout}s")
        time.sleep(0.1)


@pytest.fixture
def world() -> Iterator[ServerPool]:
    with ServerPool(1, base_port=0, seed=5, ms_per_tick=20) as pool:
        yield pool


@pytest.fixture
def replay() -> Iterator[ReplayClient]:
    signature = transition_signature(observation_space(parse_mission(MISSION)), ACTION_SPACE)
    with ReplayProcess([{"name": "mc", "max_size": 10_000, "signature": signature}]) as server:
        client = ReplayClient(server.address)
        yield client
        client.close()


# ------------------------------------------------------------- encoding (no processes)
def test_encoding_hand_computed() -> None:
    mission = parse_mission(MISSION)
    assert observation_space(mission).shape == (OBS_DIM,)
    grid = ["stone"] * 9 + ["air"] * 9 + ["water"] * 8 + ["stone_slab"]  # unknown: solid
    info = {"XPos": 32.0, "YPos": 64.0, "ZPos": -16.0, "Yaw": 90.0, "Pitch": 45.0}
    info |= {"Life": 10.0, "Food": 20, "TotalTime": 3, "cube": grid}
    v = encode_observation(info, mission)
    expected = [0.5, 1.0, -0.25, 1.0, 0.0, 0.5, 0.5, 1.0] + [1] * 9 + [0] * 17 + [1]
    assert v.dtype == np.float32
    np.testing.assert_allclose(v, expected, atol=1e-6)
    with pytest.raises(ValueError, match="cells"):
        encode_observation({**info, "cube": grid[:-1]}, mission)
    with pytest.raises(ValueError, match="ObservationFromFullStats"):
        observation_space(parse_mission(mission_xml(width=None, observations="")))


def test_action_commands_clip_and_threshold() -> None:
    text = action_commands(np.array([2.0, -0.5, 0.0, 0.25, 0.1, -0.3]))
    assert text == "move 1.000\nstrafe -0.500\nturn 0.000\npitch 0.250\njump 1\nattack 0"


# -------------------------------------------------------------- real processes
def test_actor_streams_transitions_and_reports_ticks(ray_local, world, replay) -> None:
    actor = MinecraftActor.remote(
        host="127.0.0.1", port=world.ports[0], mission_xml=MISSION, td3=TD3, seed=1,
        replay=replay, table="mc", insert_every=16,
    )  # fmt: skip
    report = ray.get(actor.run.remote(max_steps=60), timeout=60)
    assert report["actor/steps"] == 60
    assert report["replay/inserted"] == 60 and report["replay/dropped"] == 0
    assert 0.0 <= report["perf/ticks_skipped_fraction"] <= 1.0
    # Every observation counted once (real Malmo: a step may bring none, frames come at
    # 60/s and ticks at 50/s here).
    assert 0 < report["perf/ticks_seen"] <= 61
    assert 0.0 < report["perf/step_latency_ms_p50"] < 20.0  # the actor's own time per step
    (status,) = replay.info()
    assert status.size == 60
    batch = replay.sample("mc", 32)
    assert batch["obs"].shape == (32, OBS_DIM) and batch["next_obs"].shape == (32, OBS_DIM)
    # Uniform random warm-up policy: version -1, density 1 / 2^6 on the box.
    assert (batch["policy_version"] == -1).all()
    np.testing.assert_allclose(batch["log_prob"], -6 * math.log(2.0), rtol=1e-6)
    assert (np.abs(batch["action"]) <= 1.0).all()
    ray.get(actor.close.remote())
    ray.kill(actor)


def test_actor_adopts_broadcast_weights_and_records_their_log_prob(
    ray_local, world, replay
) -> None:
    broadcaster = WeightBroadcaster.remote()
    low, high = ACTION_SPACE.low, ACTION_SPACE.high
    torch.manual_seed(0)
    net = make_actor_network(OBS_DIM, 6, low, high, TD3)
    ray.get(broadcaster.publish.remote(0, [ray.put(net.state_dict())]))
    actor = MinecraftActor.remote(
        host="127.0.0.1", port=world.ports[0], mission_xml=MISSION, td3=TD3, seed=2,
        replay=replay, table="mc", broadcaster=broadcaster, insert_every=8,
    )  # fmt: skip
    report = ray.get(actor.run.remote(max_steps=40), timeout=60)
    assert report["policy/version"] == 0 and report["policy/versions_adopted"] == 1
    batch = replay.sample("mc", 64)
    mine = batch["policy_version"] == 0
    assert mine.any()
    with torch.no_grad():
        mean = net(torch.as_tensor(batch["obs"][mine])).numpy()
    # The recorded density is the Gaussian's at the unclipped sampled action.
    expected = gaussian_log_prob(batch["action"][mine], mean, TD3.exploration_noise)
    np.testing.assert_allclose(batch["log_prob"][mine], expected, rtol=1e-4, atol=1e-4)
    ray.get(actor.close.remote())
    ray.kill(actor)
    ray.kill(broadcaster)


def test_actor_reconnects_after_world_server_restart(ray_local, replay) -> None:
    pool = ServerPool(1, base_port=0, seed=5, ms_per_tick=20)
    (port,) = pool.start()
    actor = MinecraftActor.remote(
        host="127.0.0.1", port=port, mission_xml=MISSION, td3=TD3, seed=3,
        replay=replay, table="mc", insert_every=8, max_backoff_s=0.5,
    )  # fmt: skip
    run = actor.run.remote(duration_s=60)
    try:
        wait_for(lambda: ray.get(actor.report.remote())["actor/steps"] >= 20, what="20 steps")
        pool.stop()  # the world server goes away mid-episode
        time.sleep(0.5)
        pool = ServerPool(1, base_port=port, seed=5, ms_per_tick=20)
        pool.start()
        before = ray.get(actor.report.remote())["actor/steps"]
        wait_for(
            lambda: ray.get(actor.report.remote())["actor/steps"] >= before + 20,
            what="20 steps after the restart",
        )
        actor.stop.remote()
        report = ray.get(run, timeout=30)
    finally:
        pool.stop()
    assert report["net/connection_losses"] >= 1 and report["net/reconnects"] >= 1
    assert report["replay/inserted"] == report["actor/steps"] >= before + 20
    ray.get(actor.close.remote())
    ray.kill(actor)


def test_slow_actor_reports_the_ticks_it_skipped(world) -> None:
    agent = MinecraftAgent(
        host="127.0.0.1", port=world.ports[0], mission_xml=MISSION, td3=TD3, seed=5
    )
    act = agent.behaviour.act

    def slow_act(obs, rng):
        time.sleep(0.1)  # 5 ticks of 20 ms
        return act(obs, rng)

    agent.behaviour.act = slow_act
    report = agent.run(max_steps=15)
    assert report["perf/step_latency_ms_p50"] >= 100.0
    # About 4 of every 5 ticks pass unseen; at least one per step even on a busy machine.
    assert report["perf/ticks_skipped"] >= 15
    assert report["perf/ticks_skipped_fraction"] > 0.5
    agent.close()


def test_naive_loop_trains_between_steps(world) -> None:
    agent = MinecraftAgent(
        host="127.0.0.1", port=world.ports[0], mission_xml=MISSION, td3=TD3, seed=4,
        inline_updates_per_step=2, inline_learning_starts=16,
    )  # fmt: skip
    report = agent.run(max_steps=40)
    # Updates start once 16 transitions are stored: steps 16..40 do two each.
    assert report["learner/inline_updates"] == 2 * 25
    assert report["policy/version"] == 50  # it acts with the network it trains
    agent.close()
