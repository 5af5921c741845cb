"""bench/naive_loop.py, the paper's naive loop the decoupling benchmark compares with:
against a real world server it trains TD3 inside its acting loop and acts with the
network it trains."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from learner.td3.config import TD3Config
from minecraft.agent.mission_env import ENV_ID
from minecraft.sim.server import WorldServer
from minecraft.sim.timing import IDEAL
from tests.minecraft.conftest import flat_mission

_spec = importlib.util.spec_from_file_location(
    "naive_loop", Path(__file__).resolve().parents[2] / "bench" / "naive_loop.py"
)
naive_loop = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(naive_loop)


def test_naive_loop_trains_between_steps() -> None:
    # Ideal timing: one observation per step, so every step's tick is metered.
    with WorldServer(port=0, seed=7, ms_per_tick=20, timing=IDEAL) as server:
        loop = naive_loop.NaiveLoop(
            env_id=ENV_ID,
            env_kwargs={
                "address": f"127.0.0.1:{server.port}",
                "mission_xml": flat_mission(grid_radius=1, ms_per_tick=20),
            },
            td3=TD3Config(hidden_sizes=(32,), batch_size=16),
            seed=4,
            updates_per_step=2,
            learning_starts=16,
        )
        report = loop.run(max_steps=40)
        loop.close()
    # Updates start once 16 transitions are stored: steps 16..40 do two each.
    assert report["learner/inline_updates"] == 2 * 25
    assert report["policy/version"] == 50  # it acts with the network it trains
    assert report["perf/ticks_seen"] >= 40  # metered as graft's actors are
    # The behaviour's network is the trained actor itself, not a copy.
    assert loop.behaviour.network.network is loop.trainer.learner.actor
