"""The env actor over a real-time Minecraft client, against real processes: a world
server, a replay server (``graft replay serve``) and a local Ray instance. The actor
streams transitions with their behaviour log-likelihood and policy version, adopts
broadcast weights, meters the ticks it skipped, and reconnects when its world server is
killed and restarted."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import ray
import torch

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import EnvActor, Segment, VectorStepper
from actors.minecraft.agent.mission_env import ACTION_SPACE, ENV_ID, observation_space
from actors.minecraft.malmo.mission import parse_mission
from actors.minecraft.sim.pool import ServerPool
from actors.minecraft.sim.timing import IDEAL
from actors.policies import gaussian_log_prob
from actors.task import EnvSpec
from actors.transitions import replay_signature
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from service.replay.client import ReplayClient
from service.run.replay_process import ReplayProcess
from service.weights import WeightBroadcaster, WeightSubscriber
from tests.actors.minecraft.conftest import flat_mission

MISSION = flat_mission(grid_radius=1, ms_per_tick=20)
OBS_DIM = 8 + 27
TD3 = TD3Config(hidden_sizes=(32,), batch_size=16)
LOW, HIGH = ACTION_SPACE.low, ACTION_SPACE.high


def behaviour() -> GaussianBehaviour:
    torch.manual_seed(0)
    network = make_actor_network(OBS_DIM, 6, LOW, HIGH, TD3)
    return GaussianBehaviour(network, std=TD3.exploration_noise, low=LOW, high=HIGH)


def env_kwargs(port: int) -> dict[str, Any]:
    return {"address": f"127.0.0.1:{port}", "mission_xml": MISSION, "world_seed": 5}


def wait_for(predicate: Callable[[], bool], timeout: float = 30.0, what: str = "") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} not reached in {timeout}s")
        time.sleep(0.1)


@pytest.fixture
def world() -> Iterator[ServerPool]:
    # Ideal timing: every step brings one tick, so the counts below are exact.
    with ServerPool(1, base_port=0, seed=5, ms_per_tick=20, timing=IDEAL) as pool:
        yield pool


@pytest.fixture
def replay() -> Iterator[ReplayClient]:
    signature = replay_signature(observation_space(parse_mission(MISSION)), behaviour().columns())
    with ReplayProcess([{"name": "mc", "max_size": 10_000, "signature": signature}]) as server:
        client = ReplayClient(server.address)
        yield client
        client.close()


def make_actor(port: int, replay: ReplayClient, broadcaster: Any, *, seed: int) -> Any:
    return EnvActor.remote(
        env=EnvSpec(ENV_ID, env_kwargs(port)), num_envs=1, seed=seed, replay=replay,
        weights=WeightSubscriber(broadcaster), behaviour=behaviour(), steps_per_insert=8, nice=0,
    )  # fmt: skip


def test_actor_streams_transitions_and_meters_ticks(ray_local, world, replay) -> None:
    broadcaster = WeightBroadcaster.remote()
    actor = make_actor(world.ports[0], replay, broadcaster, seed=1)
    # All warm-up (no weights needed); inserts from the background thread, 4 may wait.
    segment = Segment("mc", steps=60, warmup_steps=60, pending_inserts=4)
    report = ray.get(actor.run.remote([segment]), timeout=60)
    assert report["env_steps"] == report["replay/inserted"] == 60
    assert report["perf/ticks_seen"] >= 60
    assert 0.0 <= report["perf/ticks_skipped_fraction"] <= 1.0
    assert 0.0 < report["perf/step_latency_ms_p50"] <= report["perf/step_latency_ms_p99"]
    assert report["perf/world_ticks_per_s"] > 0
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
    ray.kill(broadcaster)


def test_actor_adopts_broadcast_weights_and_records_their_log_prob(
    ray_local, world, replay
) -> None:
    broadcaster = WeightBroadcaster.remote()
    torch.manual_seed(1)
    net = make_actor_network(OBS_DIM, 6, LOW, HIGH, TD3)
    ray.get(broadcaster.publish.remote(0, [ray.put(net.state_dict())]))
    actor = make_actor(world.ports[0], replay, broadcaster, seed=2)
    report = ray.get(actor.run.remote([Segment("mc", steps=40)]), timeout=60)
    assert report["policy/version"] == 0 and report["policy/versions_adopted"] == 1
    batch = replay.sample("mc", 64)
    assert (batch["policy_version"] == 0).all()
    with torch.no_grad():
        mean = net(torch.tensor(batch["obs"])).numpy()
    # The recorded density is the Gaussian's at the unclipped sampled action.
    expected = gaussian_log_prob(batch["action"], mean, TD3.exploration_noise)
    np.testing.assert_allclose(batch["log_prob"], expected, rtol=1e-4, atol=1e-4)
    ray.get(actor.close.remote())
    ray.kill(actor)
    ray.kill(broadcaster)


def test_actor_reconnects_after_world_server_restart(ray_local, replay) -> None:
    pool = ServerPool(1, base_port=0, seed=5, ms_per_tick=20)
    (port,) = pool.start()
    broadcaster = WeightBroadcaster.remote()
    actor = make_actor(port, replay, broadcaster, seed=3)
    run = actor.run.remote([Segment("mc", steps=10**6, warmup_steps=10**6, pending_inserts=4)])

    def steps() -> int:
        return ray.get(actor.report.remote())["actor/env_steps"]

    try:
        wait_for(lambda: steps() >= 20, what="20 steps")
        pool.stop()  # the world server goes away mid-episode
        time.sleep(0.5)
        pool = ServerPool(1, base_port=port, seed=5, ms_per_tick=20)
        pool.start()
        before = steps()
        wait_for(lambda: steps() >= before + 20, what="20 steps after the restart")
        ray.get(broadcaster.stop.remote())  # the learner ends the run
        report = ray.get(run, timeout=30)
    finally:
        pool.stop()
    assert report["net/connection_losses"] >= 1 and report["net/reconnects"] >= 1
    assert report["env_steps"] >= before + 20
    # Every step but the unfinished batch the stop dropped is in the table; the lost
    # step (no successor observation) is not a transition.
    (status,) = replay.info()
    assert status.size == report["replay/inserted"]
    assert 0 <= report["env_steps"] - report["replay/inserted"] < 8
    ray.get(actor.close.remote())
    ray.kill(actor)
    ray.kill(broadcaster)


def test_a_slow_actor_meters_the_ticks_it_skipped(world) -> None:
    stepper = VectorStepper(EnvSpec(ENV_ID, env_kwargs(world.ports[0])), 1, 0)
    for _ in range(15):
        time.sleep(0.1)  # 5 ticks of 20 ms: "training inside the acting loop"
        stepper.step(np.zeros((1, 6), np.float32))
    m = stepper.meter.metrics()
    assert m["perf/step_latency_ms_p50"] >= 100.0
    # About 4 of every 5 ticks pass unseen; at least one per step even on a busy machine.
    assert m["perf/ticks_skipped"] >= 15
    assert m["perf/ticks_skipped_fraction"] > 0.5
    stepper.close()


def test_concurrent_steps_give_the_same_transitions_as_one_after_another() -> None:
    spec = EnvSpec("Pendulum-v1", {"max_episode_steps": 5})
    actions = np.random.default_rng(0).uniform(-2, 2, size=(12, 3, 1)).astype(np.float32)
    records = []
    for concurrent in (False, True):
        stepper = VectorStepper(spec, 3, seed=7, concurrent=concurrent)
        records.append([stepper.step(a) for a in actions])
        stepper.close()
    for one, other in zip(*records, strict=True):
        for key in one:
            np.testing.assert_array_equal(one[key], other[key])
    assert any(r["truncated"].any() for r in records[1])  # episodes ended and reset
