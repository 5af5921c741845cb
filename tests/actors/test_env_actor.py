"""The env actor over a real-time Minecraft client, against real processes: a world
server, a replay server (``graft replay serve``) and a local Ray instance. The actor
streams transitions with their behaviour log-likelihood and policy version, adopts
broadcast weights, meters the ticks it skipped, and reconnects when its world server is
killed and restarted."""

from __future__ import annotations

import itertools
import math
import os
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import ray
import torch
from gymnasium import spaces

from actors.behaviours.gaussian import GaussianBehaviour
from actors.env_actor import EnvActor, Segment, VectorStepper
from actors.policies import gaussian_log_prob
from actors.task import EnvSpec
from actors.transitions import replay_signature
from graft.replay_host.process import ReplayProcess
from learner.td3.builder import make_actor_network
from learner.td3.config import TD3Config
from learner.td3.networks import acting_copy
from minecraft.agent.mission_env import ACTION_SPACE, ENV_ID, observation_space
from minecraft.malmo.mission import parse_mission
from minecraft.sim.pool import ServerPool
from minecraft.sim.timing import IDEAL
from service.core import as_arrays
from service.replay.client import ReplayClient
from service.weights import WeightBroadcaster, WeightSubscriber
from tests.minecraft.conftest import flat_mission

# Real-time clients and world servers (their start-up, pacing, restarts): every test here
# mostly waits, so all run in the real-time part, beside the CPU-bound parallel part.
pytestmark = pytest.mark.serial

MISSION = flat_mission(grid_radius=1, ms_per_tick=20)
OBS_DIM = 8 + 27
TD3 = TD3Config(hidden_sizes=(32,), batch_size=16)
LOW, HIGH = ACTION_SPACE.low, ACTION_SPACE.high


def behaviour() -> GaussianBehaviour:
    torch.manual_seed(0)
    network = make_actor_network(OBS_DIM, 6, LOW, HIGH, TD3)
    return GaussianBehaviour(acting_copy(network), std=TD3.exploration_noise, low=LOW, high=HIGH)


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
    ray.get(broadcaster.publish.remote(0, [ray.put(as_arrays(net.state_dict()))]))
    actor = make_actor(world.ports[0], replay, broadcaster, seed=2)
    report = ray.get(actor.run.remote([Segment("mc", steps=40)]), timeout=60)
    assert report["policy/version"] == 0 and report["policy/versions_adopted"] == 1
    batch = replay.sample("mc", 64)
    assert (batch["policy_version"] == 0).all()
    # It acted with the weights in numpy: the actor's process never loaded torch.
    assert not ray.get(actor.__ray_call__.remote(lambda _: "torch" in sys.modules))
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


@pytest.mark.service
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


def test_asynchronous_steps_give_each_environment_the_same_transitions() -> None:
    spec = EnvSpec("Pendulum-v1", {"max_episode_steps": 5})
    actions = np.random.default_rng(0).uniform(-2, 2, size=(12, 3, 1)).astype(np.float32)
    per_env: list[dict[int, list[np.ndarray]]] = []
    for asynchronous in (False, True):
        stepper = VectorStepper(spec, 3, seed=7, asynchronous=asynchronous)
        rows: dict[int, list[np.ndarray]] = {0: [], 1: [], 2: []}
        steps = [0, 0, 0]  # each environment takes its own actions, in its own order
        while min(steps) < len(actions):
            envs = np.array([e for e in stepper.idle if steps[e] < len(actions)], np.int64)
            record = stepper.step(np.stack([actions[steps[e], e] for e in envs]), envs)
            for e in envs:
                steps[e] += 1
            for j, e in enumerate(stepper.stepped):
                fields = ("obs", "reward", "terminated", "truncated", "next_obs")
                rows[e].append(np.concatenate([np.ravel(record[k][j]) for k in fields]))
        while stepper.in_flight:
            stepper.step(np.zeros((0, 1), np.float32), np.zeros(0, np.int64))
        per_env.append(rows)
        stepper.close()
    for e in range(3):
        np.testing.assert_array_equal(np.stack(per_env[0][e]), np.stack(per_env[1][e]))
    assert sum(bool(r[3]) for r in per_env[1][0]) >= 2  # episodes ended and reset


class ThreadNiceness(gym.Env):
    """Observes the niceness of the thread that steps it (on Linux, each thread's own)."""

    observation_space = spaces.Box(-20.0, 20.0, shape=(1,), dtype=np.float32)
    action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed: Any = None, options: Any = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return self._niceness(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        return self._niceness(), 0.0, False, False, {}

    @staticmethod
    def _niceness() -> np.ndarray:
        return np.array([os.getpriority(os.PRIO_PROCESS, 0)], np.float32)


def test_asynchronous_environments_step_at_the_actors_niceness(ray_local) -> None:
    """Each environment's thread (started when the actor is made, in a thread of Ray's at
    nice 15) takes the actor's niceness, as the acting thread does: otherwise the
    real-time clients' socket and decoding work waits behind every other process."""
    net = make_actor_network(1, 1, np.array([-1.0]), np.array([1.0]), TD3)
    slow = GaussianBehaviour(acting_copy(net), std=0.1, low=np.array([-1.0]), high=np.array([1.0]))
    signature = replay_signature(ThreadNiceness.observation_space, slow.columns())
    with ReplayProcess([{"name": "t", "max_size": 1000, "signature": signature}]) as server:
        replay = ReplayClient(server.address)
        broadcaster = WeightBroadcaster.remote()
        here = Path(__file__).resolve()
        folders = (str(here.parent), str(here.parents[2]))  # this module, and `tests`
        actor = EnvActor.remote(
            env=EnvSpec(f"{__name__}:ThreadNiceness", import_path=folders), num_envs=3, seed=0,
            replay=replay, weights=WeightSubscriber(broadcaster), behaviour=slow,
            steps_per_insert=4, nice=19, async_envs=True,
        )  # fmt: skip
        segment = Segment("t", steps=48, warmup_steps=48)
        report = ray.get(actor.run.remote([segment]), timeout=60)
        assert report["actor/nice"] == 19
        batch = replay.sample("t", 48)
        assert set(batch["obs"].ravel()) == set(batch["next_obs"].ravel()) == {19.0}
        ray.get(actor.close.remote())
        ray.kill(actor)
        ray.kill(broadcaster)
        replay.close()


_WORLDS: list[str] = []
"""Addresses `pooled_mission` hands out, one world server per environment."""
_made = itertools.count()


def pooled_mission(*, max_episode_steps: int) -> gym.Env:
    """The next of `_WORLDS`' real-time mission environments (this process only)."""
    address = _WORLDS[next(_made) % len(_WORLDS)]
    mission = flat_mission(grid_radius=1, ms_per_tick=50)
    return gym.make(ENV_ID, address=address, mission_xml=mission, world_seed=5,
                    max_episode_steps=max_episode_steps)  # fmt: skip


@pytest.mark.slow
def test_asynchronous_clients_skip_no_ticks_where_lock_step_ones_wait_for_each_other() -> None:
    """Four real-time clients (real Malmo timing: 20 ticks/s, 60 frames/s, a mission loads
    for a second) with short episodes. In lock-step each step waits for every client's
    next tick and for any client's reset, so the others skip ticks meanwhile."""
    spec = EnvSpec(f"{__name__}:pooled_mission", {"max_episode_steps": 30})
    skipped = {}
    with ServerPool(4, base_port=0, seed=5, ms_per_tick=50) as pool:
        _WORLDS[:] = [f"127.0.0.1:{p}" for p in pool.ports]
        for asynchronous in (False, True):
            stepper = VectorStepper(spec, 4, seed=0, asynchronous=asynchronous)
            for seconds in (1.0, 6.0):  # metered after the first second
                stepper.meter.restart()
                t0 = time.monotonic()
                while time.monotonic() - t0 < seconds:
                    envs = stepper.idle
                    stepper.step(np.zeros((len(envs), 6), np.float32), envs)
            skipped[asynchronous] = stepper.meter.metrics()["perf/ticks_skipped_fraction"]
            assert len(stepper.finished_returns) >= 4  # every client's episode restarted
            stepper.close()
    assert skipped[True] <= 0.02 and skipped[False] >= 0.1, skipped
