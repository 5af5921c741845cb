"""`graft tune`: the bottleneck rule, the grid, and the bottleneck named in three
constructed cases run through the real pipeline (replay server, Ray actors, broadcast)."""

from __future__ import annotations

import time

import pytest
import ray

from graft.orchestration.kept import BROADCASTER, ENV_ACTORS, KEPT
from graft.tuning.grid import Costs, parse_grid, plan
from graft.tuning.measure import bottleneck
from graft.tuning.report import preset_lines, table
from graft.tuning.sweep import _drain_until_ended, run_point
from graft.validation import ConfigError


@pytest.mark.parametrize(
    ("learner_wait", "publish", "actor_hold", "skipped", "expected"),
    [
        (0.02, 0.01, 0.60, None, "learner"),  # actors held, learner never waits
        (0.90, 0.01, 0.03, None, "actors"),  # learner starves, actors never held
        (0.90, 0.01, 0.70, None, "replay"),  # both held: the table is the constraint
        (0.05, 0.01, 0.05, None, "none"),  # both busy
        (0.02, 0.40, 0.60, None, "broadcast"),  # the learner mostly publishes
        (0.02, 0.01, 0.60, 0.05, "actors"),  # real-time actors miss ticks first
        (0.02, 0.01, 0.60, 0.005, "learner"),  # a few skipped ticks are tolerated
    ],
)
def test_bottleneck_rule(learner_wait, publish, actor_hold, skipped, expected):
    got = bottleneck(
        learner_wait=learner_wait, publish=publish, actor_hold=actor_hold, skipped=skipped
    )
    assert got == expected


def test_grid_is_the_product_of_the_knobs():
    grid = parse_grid(["actors=1,2", "batch_size=64,128", "step_cost_ms=0.5"])
    points = plan("pendulum-td3", grid, overrides={}, costs=Costs(), address="local")
    assert [(p.config.num_actors, p.config.td3.batch_size) for p in points] == [
        (1, 64), (1, 128), (2, 64), (2, 128)
    ]  # fmt: skip
    assert {p.costs.step_cost_ms for p in points} == {0.5}
    assert points[0].config.learning_starts == 2 * 64  # sampling starts at two batches


@pytest.mark.parametrize(
    ("grid", "message"),
    [
        (["actors"], "expected name=v1,v2"),
        (["actors=1", "actors=2"], "given twice"),
        (["batchsize=64"], "batchsize"),
        (["actors=0"], "num_actors=0 must be >= 1"),
        (["learner=fast"], "learner='fast' is unknown"),
        (["actors=4", "actor_cpus=1"], "need 4 CPUs"),
        (["replay_shards=3"], "replay.shards=3 needs num_actors >= 3"),
    ],
)
def test_bad_grid_is_one_line_before_anything_starts(grid, message):
    with pytest.raises(ConfigError, match=message):
        plan("pendulum-td3", parse_grid(grid), overrides={}, costs=Costs(), address="local")


def test_preset_lines_nest_section_fields_and_convert_samples_per_insert():
    best = {"actors": 2, "batch_size": 128, "samples_per_insert": 64, "step_cost_ms": 1.0}
    lines = preset_lines(best, list(best), "td3")
    assert lines == [
        "num_actors: 2",
        "updates_per_env_step: 0.5",
        "td3:",
        "  batch_size: 128",
        "# step_cost_ms: 1.0 (a property of the simulated parts)",
    ]


SMALL = {"td3.hidden_sizes": [16, 16], "num_actors": 1}


def _point(costs: Costs, **overrides):
    (point,) = plan(
        "pendulum-td3", {}, overrides={**SMALL, **overrides}, costs=costs, address="local"
    )
    return point


@pytest.mark.slow
@pytest.mark.parametrize(
    ("case", "overrides", "costs", "expected"),
    [
        # 100 ms of CPU per update: the rate limiter holds the actors for the learner. (A
        # slack of 32 env steps, one insert: with the preset's 200, actors slowed by a
        # loaded machine may not have run that far ahead by the end of the window.)
        (
            "slow learner",
            {"slack_env_steps": 32},
            Costs(learner="cost", learner_cost_ms=100.0),
            "learner",
        ),
        # One environment taking 20 ms a step: a learner that only draws batches starves.
        # (Rare publishes: on a loaded machine each may take a large share of this learner's
        # little time, which the rule would rightly call a broadcast bottleneck.)
        (
            "slow actor",
            # Batches of 32: the table starts sampling at 64 steps, 1.3 s of this actor's.
            {"envs_per_actor": 1, "publish_every": 1000, "td3.batch_size": 32},
            Costs(learner="drain", step_latency_ms=20.0),
            "actors",
        ),
        # 2,048 samples per inserted item: the limiter holds inserts while the learner,
        # which does no work, waits on sampling.
        (
            "rate limiter",
            {"publish_every": 1000},
            Costs(learner="drain", samples_per_insert=2048.0),
            "replay",
        ),
    ],
)
@pytest.mark.serial  # it measures waits in real time: a starved replay server reads as one
def test_tune_names_the_bottleneck(ray_local, case, overrides, costs, expected):
    row = run_point(_point(costs, **overrides), warmup_s=2.0, measure_s=4.0, address="local")
    # Its actor ended its run and waits for the next point, even one the rate limiter held
    # (the point drew batches until the actor's held inserts were admitted).
    assert len(KEPT.held(ENV_ACTORS)) == 1, case
    detail = {k: row[k] for k in ("learner_wait", "actor_insert_wait", "publish_fraction")}
    assert row["bottleneck"] == expected, f"{case}: {row['bottleneck']} from {detail}"
    assert row["learner_updates_per_s"] > 0  # the pipeline ran (a held actor may insert nothing)
    # The split of the actors' insert wait adds up to it: the wait is spent in insert calls,
    # held by the limiter or not, including a call held across the window's edges. (Counting
    # a held call only once it returned read 107-151 % of a 99 % wait for the slow learner.)
    split = row["insert_limiter_s_per_s"] + row["insert_network_s_per_s"]
    assert split == pytest.approx(row["actor_insert_wait"], abs=0.1), (case, split, detail)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--grid", "batchsize=64"], "graft tune: unknown field batchsize"),
        (["--measure", "0"], "graft tune: --measure=0.0 must be > 0 seconds"),
        (["--step-cost-ms", "-1"], "graft tune: step_cost_ms=-1.0 must be >= 0"),
    ],
)
def test_graft_tune_refuses_bad_input_in_one_line(argv, message, capsys):
    from graft.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["tune", "--address", "local", *argv])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(message) and "\n" not in err


def test_replay_shards_is_a_knob_and_its_preset_line_is_nested():
    points = plan(
        "pendulum-td3", parse_grid(["replay_shards=1,2"]), overrides={}, costs=Costs(),
        address="local",
    )  # fmt: skip
    assert [p.config.replay.shards for p in points] == [1, 2]
    assert preset_lines({"replay_shards": 2}, ["replay_shards"], "td3") == [
        "replay:",
        "  shards: 2",
    ]


@pytest.mark.slow
def test_tune_over_replay_shards_spreads_inserts_over_every_shard(ray_local):
    points = plan(
        "pendulum-td3", parse_grid(["replay_shards=1,2"]),
        overrides={**SMALL, "num_actors": 2}, costs=Costs(learner="drain", step_latency_ms=2.0),
        address="local",
    )  # fmt: skip
    rows, helpers = [], []
    for point in points:
        rows.append(run_point(point, warmup_s=0.5, measure_s=1.5, address="local"))
        helpers.append({a._actor_id for role in (ENV_ACTORS, BROADCASTER) for a in KEPT.held(role)})
    one, two = rows
    assert len(helpers[0]) == 3 and helpers[1] == helpers[0]  # the second point took them on
    assert "/" not in one["shard_inserted_per_s"] and one["inserted_per_s"] > 0
    per_shard = [float(v) for v in two["shard_inserted_per_s"].split(" / ")]
    assert len(per_shard) == 2 and min(per_shard) > 0, two  # each actor has its own shard
    assert sum(per_shard) == pytest.approx(two["inserted_per_s"], abs=1.0)
    assert len(two["shard_cpu_replay"].split(" / ")) == 2
    assert two["learner_updates_per_s"] > 0  # the learner sampled across the shards
    printed = table(rows, ["replay_shards"])
    assert "inserted/s per shard" in printed and "CPU replay per shard" in printed


def test_a_point_whose_table_went_away_still_waits_for_its_actors(ray_local, replay_client):
    """Draining after the window: a stream that ends (here closed; a server gone raises
    ReplayError) stops the draws, and the runs still get the rest of the limit."""
    stream = replay_client.sample_stream("transitions", 4)
    stream.close()
    run = ray.remote(lambda: time.sleep(0.3)).remote()  # an actor's run ending a moment later
    assert _drain_until_ended(stream, [run], limit_s=10.0) == {run.hex()}
