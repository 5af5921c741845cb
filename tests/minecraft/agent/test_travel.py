"""The travel task: its reward (progress, per-tick cost, stuck penalty) with hand-computed
values, the route and mission draw, the observation and μ(s) plumbing, and the gym
environment against a real world server over MalmoEnv."""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from actors.behaviours.backbone import compose_action
from minecraft.agent.leaves.percept import RADIUS, SIDE, Percept
from minecraft.agent.travel_control import (
    JUMP_OFF,
    JUMP_ON,
    MU,
    OBS_DIM,
    TreeSteering,
    compose_commands,
    local_goal,
    observation,
    to_agent_frame,
)
from minecraft.agent.travel_env import ENV_ID, TravelBackbone
from minecraft.agent.travel_task import (
    RewardConfig,
    StuckDetector,
    TravelMission,
    TravelReward,
    draw_missions,
    mission_pool,
    route_to_go,
)
from minecraft.blocks import ID
from minecraft.sim import worldgen
from minecraft.sim.server import WorldServer
from tests.learner.helpers import FixedRows

ROUTE = ((0, 4, 0), (0, 4, 1), (0, 4, 2), (1, 4, 2))


# ------------------------------------------------------------------ reward
def test_route_to_go_hand_computed() -> None:
    # At the start cell's centre: 3 cells along the route, or straight to the last cell
    # (1, 4, 2): sqrt(1 + 4) = 2.236, the shorter (the route is a staircase of cells).
    assert route_to_go(ROUTE, 0.5, 4.0, 0.5) == pytest.approx(math.sqrt(5.0))
    # Between cells 1 and 2: 1 + 0.5 via cell 2, or sqrt(1 + 0.25) straight to the end.
    assert route_to_go(ROUTE, 0.5, 4.0, 2.0) == pytest.approx(math.sqrt(1.25))
    # A long straight route: cells left plus the way to the nearest one.
    straight = tuple((0, 4, i) for i in range(10))
    assert route_to_go(straight, 0.5, 4.0, 2.5) == pytest.approx(7.0)
    assert route_to_go(straight, 0.5, 4.0, 2.9) == pytest.approx(6.6)
    # At the destination's centre: 0. Beside it, 0.5 off: 0.5.
    assert route_to_go(ROUTE, 1.5, 4.0, 2.5) == pytest.approx(0.0)
    assert route_to_go(ROUTE, 2.0, 4.0, 2.5) == pytest.approx(0.5)
    # Cells more than 2 blocks above or below do not count (a cliff top is not progress)...
    high = ((0, 4, 0), (5, 20, 0))
    assert route_to_go(high, 5.5, 4.0, 0.5) == pytest.approx(1.0 + 5.0)
    # ...unless no cell is within 2 blocks of height: then the nearest of all.
    assert route_to_go(high, 5.5, 10.0, 0.5) == pytest.approx(0.0)


def test_route_to_go_walking_a_looping_route_is_progress() -> None:
    # A U: up x = 0 (z 0..9), across z = 9, down x = 8 (z 9..0): 27 cells. The last cell
    # is 8 blocks from the start in a straight line, which is not the way.
    u = (
        tuple((0, 4, k) for k in range(10))
        + tuple((i, 4, 9) for i in range(1, 9))
        + tuple((8, 4, k) for k in range(8, -1, -1))
    )
    assert len(u) == 27
    assert route_to_go(u, 0.5, 4.0, 0.5) == pytest.approx(26.0)
    # Each block walked up the first arm is a block of progress.
    assert route_to_go(u, 0.5, 4.0, 5.5) == pytest.approx(21.0)
    # Off the route (4 blocks beside cell 2, the nearest): that cell's 24 + the 4 back.
    assert route_to_go(u, -3.5, 4.0, 2.5) == pytest.approx(28.0)
    # Within 3 blocks the straight way counts: 2.5 beside cell 0, 25 + hypot(2.5, 1) via
    # cell 1 (cell 2 is hypot(2.5, 2) = 3.2 away: not counted).
    assert route_to_go(u, -2.0, 4.0, 0.5) == pytest.approx(25.0 + math.hypot(2.5, 1.0))


@pytest.mark.parametrize(
    ("phis", "expected"),
    [
        # 0.2 blocks of progress, then 0.1: r = Δφ - 0.05
        ([3.0, 2.8, 2.7], [0.2 - 0.05, 0.1 - 0.05]),
        # Walking away is negative progress.
        ([3.0, 3.3], [-0.3 - 0.05]),
    ],
)
def test_reward_progress_and_tick_cost(phis: list[float], expected: list[float]) -> None:
    reward = TravelReward(RewardConfig(tick_cost=0.05, stuck_penalty=2.0, stuck_ticks=40))
    reward.reset(phis[0])
    got = [reward.step(phi)[0] for phi in phis[1:]]
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_stuck_penalty_fires_every_k_ticks_without_progress() -> None:
    cfg = RewardConfig(
        progress_scale=1.0, tick_cost=0.05, stuck_penalty=2.0, stuck_ticks=3, stuck_progress=1.0
    )
    reward = TravelReward(cfg)
    reward.reset(10.0)
    # 0.4 + 0.4 blocks: best improves by < 1 block, so these ticks count as no progress.
    r1, s1 = reward.step(9.6)
    r2, s2 = reward.step(9.2)
    r3, s3 = reward.step(9.2)  # third tick without 1 block of progress: stuck
    assert (s1, s2, s3) == (False, False, True)
    assert r1 == pytest.approx(0.4 - 0.05)
    assert r3 == pytest.approx(0.0 - 0.05 - 2.0)
    # A full block below the best (10.0) resets the counter: no event for 3 more ticks.
    assert reward.step(8.9) == (pytest.approx(0.3 - 0.05), False)
    assert [reward.step(8.9)[1] for _ in range(3)] == [False, False, True]
    assert reward.stuck.events == 2


def test_stuck_detector_counts_from_the_best_progress() -> None:
    d = StuckDetector(ticks=2, progress=1.0)
    d.reset(5.0)
    assert [d.update(x) for x in (4.0, 4.5, 4.9)] == [False, False, True]
    assert d.events == 1 and d.best == 4.0


def test_steps_of_several_ticks_count_every_tick() -> None:
    # K = 3; steps of 2 ticks (a slow client): the second step reaches 4 ticks without
    # progress (1 event, 1 tick carried), the third 6 → a second event at tick 6.
    cfg = RewardConfig(tick_cost=0.05, stuck_penalty=2.0, stuck_ticks=3, stuck_progress=1.0)
    reward = TravelReward(cfg)
    reward.reset(10.0)
    assert reward.step(10.0, ticks=2) == (pytest.approx(-0.1), False)
    assert reward.step(10.0, ticks=2) == (pytest.approx(-0.1 - 2.0), True)
    assert reward.step(9.5, ticks=2) == (pytest.approx(0.5 - 0.1 - 2.0), True)
    assert reward.stuck.events == 2
    # A gap of 7 ticks (a real-time client missed frames) holds two events.
    assert reward.step(9.5, ticks=7) == (pytest.approx(-0.35 - 4.0), True)
    assert reward.stuck.events == 4


def test_reward_config_refuses_bad_values_naming_the_field() -> None:
    with pytest.raises(ValueError, match="stuck_ticks"):
        RewardConfig(stuck_ticks=0)
    with pytest.raises(ValueError, match="stuck_progress"):
        RewardConfig(stuck_progress=0.0)
    with pytest.raises(ValueError, match="tick_cost"):
        RewardConfig(tick_cost=-1.0)


# ------------------------------------------------------------------ missions
def test_missions_are_seeded_walkable_and_in_range() -> None:
    a = draw_missions(3, 3, random.Random(0), terrain=worldgen.generate(3))
    b = draw_missions(3, 3, random.Random(0), terrain=worldgen.generate(3))
    assert a == b
    for m in a:
        start = (math.floor(m.start[0]), int(m.start[1]), math.floor(m.start[2]))
        assert m.route[0] == start and m.route[-1] == m.destination
        d = math.hypot(m.destination[0] - start[0], m.destination[2] - start[2])
        assert 10.0 <= d <= 30.0
        for u, v in zip(m.route, m.route[1:], strict=False):
            assert abs(u[0] - v[0]) + abs(u[2] - v[2]) == 1  # 4-neighbour moves
            assert -3 <= v[1] - u[1] <= 1  # one-block jumps, drops of up to 3


# Drawn by the code before the terrain became an argument (the simulator's worldgen then
# imported by travel_task): the same seeds must keep giving the same missions.
RECORDED_POOL = [  # mission_pool(worlds 0-3, 2 per world, seed=0): world, start, destination
    (0, (0.5, 69.0, 0.5), (8, 70, 12)),
    (0, (0.5, 69.0, 0.5), (11, 71, -1)),
    (1, (-1.5, 65.0, 1.5), (-25, 68, -2)),
    (1, (-1.5, 65.0, 1.5), (-6, 65, -13)),
    (2, (0.5, 66.0, 0.5), (18, 69, 8)),
    (2, (0.5, 66.0, 0.5), (16, 69, -14)),
    (3, (-3.5, 65.0, 6.5), (8, 67, 29)),
    (3, (-3.5, 65.0, 6.5), (-4, 63, -10)),
]
RECORDED_ROUTES_SHA256 = "0005a8c13cd2fbf659d48602ca653673c7876f5f5dde0c3d5da0cef6124f6ab0"


def _routes_digest(missions: list[TravelMission]) -> str:
    routes = [[list(c) for c in m.route] for m in missions]
    return hashlib.sha256(json.dumps(routes).encode()).hexdigest()


def test_mission_pool_is_the_recorded_one() -> None:
    missions = mission_pool([0, 1, 2, 3], 2, seed=0, terrain_of=worldgen.generate)
    assert [(m.world_seed, m.start, m.destination) for m in missions] == RECORDED_POOL
    assert _routes_digest(missions) == RECORDED_ROUTES_SHA256


def test_env_draws_the_recorded_mission_from_the_simulator_terrain() -> None:
    """The default ``terrain`` import string is the simulator's generator."""
    env = gym.make(ENV_ID, world_seeds=(1000, 1001, 1002, 1003))
    try:
        env.reset(seed=11)
        m = env.unwrapped.mission
        assert (m.world_seed, m.start, m.destination) == (1003, (0.5, 66.0, 0.5), (25, 69, -16))
        assert _routes_digest([m]) == (
            "4838bbe602cfa54564781a81a854756f8fc2bc57c93383c04d12c36258dee6e3"
        )
    finally:
        env.close()


def test_env_refuses_a_bad_import_string_at_once() -> None:
    with pytest.raises(ValueError, match="package.module:name"):
        gym.make(ENV_ID, terrain="minecraft.sim.worldgen")
    with pytest.raises(ValueError, match="has no nope"):
        gym.make(ENV_ID, world_server="minecraft.sim.server:nope")


# ------------------------------------------------------------------ observation and μ(s)
def _flat_percept(x: float, z: float, yaw: float = 0.0) -> Percept:
    """A percept standing on a flat floor (solid below the feet level)."""
    ids = np.zeros((SIDE, SIDE, SIDE), np.uint8)
    ids[:RADIUS, :, :] = ID["stone"]
    return Percept(x=x, y=4.0, z=z, yaw=yaw, ids=ids)


def test_agent_frame() -> None:
    # Yaw 0 faces +z: +z is forward; strafe (right) is -x (world.py).
    assert to_agent_frame(0.0, 1.0, 0.0) == pytest.approx((1.0, 0.0))
    assert to_agent_frame(-1.0, 0.0, 0.0) == pytest.approx((0.0, 1.0))
    # Yaw 90 faces -x.
    assert to_agent_frame(-1.0, 0.0, 90.0) == pytest.approx((1.0, 0.0), abs=1e-9)


def test_local_goal_is_the_furthest_route_cell_in_view() -> None:
    route = tuple((0, 4, i) for i in range(20))
    assert local_goal(route, 0, (0, 4, 0)) == (6, (0, 4, 6))
    assert local_goal(route, 10, (0, 4, 10)) == (16, (0, 4, 16))
    assert local_goal(route, 18, (0, 4, 18)) == (19, (0, 4, 19))


def test_tree_steering_walks_along_the_route_on_flat_ground() -> None:
    steering = TreeSteering()
    route = tuple((0, 4, i) for i in range(10))
    mu, step = steering(_flat_percept(0.5, 0.5), route)
    # Straight ahead (+z at yaw 0), full speed, no jump; the next A* cell is one ahead.
    np.testing.assert_allclose(mu, [1.0, 0.0, 0.0, JUMP_OFF], atol=1e-6)
    assert step == (0, 4, 1)
    # Facing +x (yaw 270): +z is on the right, i.e. strafe +1.
    mu, _ = steering(_flat_percept(0.5, 0.5, yaw=270.0), route)
    np.testing.assert_allclose(mu, [0.0, 1.0, 0.0, JUMP_OFF], atol=1e-6)


def test_tree_steering_jumps_onto_a_step() -> None:
    p = _flat_percept(0.5, 0.5)
    p.ids[RADIUS, RADIUS + 1, RADIUS] = ID["stone"]  # a block at (0, 4, 1): the step up
    route = ((0, 4, 0), (0, 5, 1), (0, 5, 2))
    mu, step = TreeSteering()(p, route)
    assert step == (0, 5, 1)
    assert mu[3] == JUMP_ON and mu[0] > 0.9


def test_observation_layout_and_backbone_reads_mu() -> None:
    p = _flat_percept(0.5, 0.5)
    mu = np.array([0.25, -0.5, 0.0, JUMP_ON], np.float32)
    obs = observation(
        p, mu=mu, waypoint=(0, 4, 2), destination=(0, 6, 16), previous=(0.5, 4.0, 0.3),
        stuck_fraction=0.25,
    )  # fmt: skip
    assert obs.shape == (OBS_DIM,) and obs.dtype == np.float32
    np.testing.assert_allclose(obs[:8], [0.5 / 64, 4 / 64, 0.5 / 64, 0, 1, 0, 1, 1], atol=1e-6)
    crop = obs[8:108].reshape(4, 5, 5)  # [dy+1, dz+2, dx+2]
    assert crop[0].all() and not crop[1:].any()  # the floor below, air above
    np.testing.assert_allclose(obs[108:111], [2.0 / 2, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(obs[111:114], [16.0 / 32, 0.0, 2.0 / 8], atol=1e-6)
    np.testing.assert_allclose(obs[114:117], [0.2 / (4.317 / 20), 0.0, 0.0], atol=1e-5)
    np.testing.assert_allclose(obs[117:120], [1.0, 0.0, 0.25])
    np.testing.assert_allclose(obs[MU], mu)
    np.testing.assert_allclose(TravelBackbone()(obs[None]), mu[None])
    # The same displacement over a step of 2 ticks is half the velocity per tick.
    slow = observation(
        p, mu=mu, waypoint=(0, 4, 2), destination=(0, 6, 16), previous=(0.5, 4.0, 0.3),
        stuck_fraction=0.25, elapsed=2,
    )  # fmt: skip
    np.testing.assert_allclose(slow[114:117], obs[114:117] / 2, atol=1e-6)
    # The presets name the same μ by import string; graft calls it on whole batches.
    from gymnasium import spaces

    from actors.hardcoded import CallablePolicy, make_hardcoded_policy
    from graft.config import load_preset

    box = spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32)
    for preset in ("minecraft-backbone", "minecraft-options"):
        spec = load_preset(preset).hardcoded_policy
        policy = make_hardcoded_policy(spec, box, spaces.Box(-1.0, 1.0, (4,), np.float32))
        assert isinstance(policy, CallablePolicy) and policy.batched
        assert isinstance(policy.policy, TravelBackbone)
        np.testing.assert_allclose(policy(np.stack([obs, obs])), np.stack([mu, mu]))


def test_backbone_action_and_commands() -> None:
    mu = np.array([[1.0, 0.2, 0.0, JUMP_OFF]], np.float32)
    # A correction of +0.8 on jump turns it on; move stays clipped at 1.
    a = compose_action(
        mu, np.array([[0.5, 0.3, -2.0, 0.8]]), limit=1.0, low=-np.ones(4), high=np.ones(4)
    )
    np.testing.assert_allclose(a, [[1.0, 0.5, -1.0, 0.3]], atol=1e-6)
    assert compose_commands(a[0], pitch=0.5) == (
        "move 1.000\nstrafe 0.500\nturn -1.000\npitch 0.500\njump 1"
    )


# ------------------------------------------------------------------ the environment
@pytest.mark.parametrize("ticks_per_step", [1, 3])
def test_env_over_malmoenv_tree_reaches_the_destination(ticks_per_step: int) -> None:
    """The tree alone (a = μ(s)) on one seeded mission, a real world server on a socket;
    with 3 ticks per step each step advances 3 game ticks (the last may end early)."""
    missions = draw_missions(2, 1, random.Random(5), terrain=worldgen.generate(2))
    env = gym.make(ENV_ID, missions=missions, max_ticks=400, ticks_per_step=ticks_per_step)
    try:
        obs, _ = env.reset(seed=0)
        backbone = TravelBackbone()
        total, phi0 = 0.0, route_to_go(missions[0].route, *missions[0].start)
        steps = 0
        for _ in range(400):
            obs, r, terminated, truncated, info = env.step(backbone(obs))
            total, steps = total + r, steps + 1
            if terminated or truncated:
                break
        assert info["arrived"] and terminated and not truncated
        assert (steps - 1) * ticks_per_step < info["ticks"] <= steps * ticks_per_step
        # Rewards telescope: Σ r = φ0 − φ_end − 0.05·ticks − 2·stuck events.
        expected = phi0 - info["phi"] - 0.05 * info["ticks"] - 2.0 * info["stuck_events"]
        assert total == pytest.approx(expected, abs=1e-4)
    finally:
        env.close()


_WITHOUT_SIM = """
import json, sys

class NoSimulator:  # as if minecraft/sim/ were deleted
    def find_spec(self, name, path=None, target=None):
        if name == "minecraft.sim" or name.startswith("minecraft.sim."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NoSimulator())
import gymnasium as gym
from minecraft.agent.travel_env import ENV_ID, TravelBackbone
from minecraft.agent.travel_task import TravelMission

address, m = sys.argv[1], json.loads(sys.argv[2])
mission = TravelMission(
    m["world_seed"], tuple(m["start"]), tuple(m["destination"]), tuple(map(tuple, m["route"]))
)
env = gym.make(ENV_ID, address=address, missions=[mission], max_ticks=400)
obs, _ = env.reset(seed=0)
for _ in range(400):
    obs, _, terminated, truncated, info = env.step(TravelBackbone()(obs))
    if terminated or truncated:
        break
env.close()
print(json.dumps({"arrived": info["arrived"], "modules": sorted(sys.modules)}))
"""


@pytest.mark.service
def test_env_plays_a_given_address_without_the_simulator(server: WorldServer) -> None:
    """The agent runs against a Minecraft at an address (here a simulated one, in this
    process) with the simulator package unimportable in its own process."""
    m = draw_missions(2, 1, random.Random(5), terrain=worldgen.generate(2))[0]
    mission = {"world_seed": m.world_seed, "start": m.start, "destination": m.destination,
               "route": m.route}  # fmt: skip
    root = str(Path(__file__).resolve().parents[3])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([root, os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run(
        [sys.executable, "-c", _WITHOUT_SIM, f"127.0.0.1:{server.port}", json.dumps(mission)],
        capture_output=True, text=True, env=env, timeout=120, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout)
    assert out["arrived"]
    assert not [name for name in out["modules"] if name.startswith("minecraft.sim")]


def test_env_refuses_bad_timing_settings() -> None:
    with pytest.raises(ValueError, match="ticks_per_step=0"):
        gym.make(ENV_ID, ticks_per_step=0)
    with pytest.raises(ValueError, match="synchronous world"):
        gym.make(ENV_ID, ticks_per_step=2, real_time=True)


def test_run_config_env_kwargs_reach_the_environment() -> None:
    from graft.config import load_preset

    config = load_preset("minecraft-backbone", **{"env_kwargs.ticks_per_step": 4})
    env = config.make_env()
    try:
        assert env.unwrapped.ticks_per_step == 4
    finally:
        env.close()
    bad = load_preset("minecraft-backbone", **{"env_kwargs.ticks_per_stpe": 4})
    with pytest.raises(ValueError, match="ticks_per_stpe"):
        bad.make_env()
    weights = load_preset("minecraft-backbone", **{"env_kwargs.reward": {"tick_cost": 0.1}})
    env = weights.make_env()
    try:
        assert env.unwrapped.reward_fn.config == RewardConfig(tick_cost=0.1)
    finally:
        env.close()
    typo = load_preset("minecraft-backbone", **{"env_kwargs.reward": {"tick_cots": 0.1}})
    with pytest.raises(ValueError, match="tick_cots"):
        typo.make_env()


def test_occupancy_is_sampled_in_the_agent_frame() -> None:
    from minecraft.agent.travel_control import egocentric_occupancy

    p = _flat_percept(0.5, 0.5, yaw=90.0)  # facing -x; right is -z
    p.ids[RADIUS, RADIUS, RADIUS - 1] = ID["stone"]  # (-1, 4, 0): one block ahead, feet level
    p.ids[RADIUS + 1, RADIUS - 1, RADIUS] = ID["stone"]  # (0, 5, -1): on the right, head level
    occ = egocentric_occupancy(p).reshape(4, 5, 5)  # [dy+1, forward, right]
    assert occ[0].all()  # the floor
    assert occ[1, 3, 2] == 1.0 and occ[1].sum() == 1.0  # 0.8 ahead only (1.6 is past it)
    assert occ[2, 2, 3] == 1.0 and occ[2].sum() == 1.0
    assert occ[3].sum() == 0.0


def test_recovery_gate_drops_the_correction_once_progress_stalls() -> None:

    from actors.behaviours.backbone import BackboneBehaviour
    from minecraft.agent.travel_control import MU, OBS_DIM, STUCK
    from minecraft.agent.travel_env import TravelBackbone, correction_trusted

    obs = np.zeros((3, OBS_DIM), np.float32)
    obs[:, MU] = [0.2, 0.0, 0.0, -1.0]
    obs[:, STUCK] = [0.0, 0.45, 0.55]  # ticks without progress / K
    behaviour = BackboneBehaviour(
        FixedRows([[0.5] * 4]),  # a correction network pushing +0.5 on every axis
        TravelBackbone(),
        limit=0.5,
        std=0.1,
        prefill_std=0.1,
        low=-np.ones(4),
        high=np.ones(4),
        gate=correction_trusted,
    )
    np.testing.assert_array_equal(correction_trusted(obs), [True, True, False])
    # μ + 0.5 where the correction is trusted, μ alone on the stalled row.
    np.testing.assert_allclose(
        behaviour.greedy(obs),
        [[0.7, 0.5, 0.5, -0.5], [0.7, 0.5, 0.5, -0.5], [0.2, 0.0, 0.0, -1.0]],
        rtol=1e-6,
    )
