"""How the launcher splits phases among actors, and how their inserts go out: a table
whose rate limiter holds samples per insert has every insert waited for (the limiter
paces acting); a table that never holds inserts gets a queue of background inserts."""

from __future__ import annotations

from actors.env_actor import Segment
from graft.orchestration.roles import PENDING_INSERTS, actor_segments
from learner.agent import Phase


def test_rate_limited_phases_wait_for_each_insert() -> None:
    demos = Phase("demos", env_steps=1001, updates=0, min_size=100, warmup_steps=1001)
    online = Phase(
        "transitions", env_steps=5000, updates=4000, min_size=1000, samples_per_insert=256.0,
        warmup_steps=1000,
    )  # fmt: skip
    empty = Phase("pretrain", env_steps=0, updates=500, min_size=1)
    assert actor_segments([demos, empty, online], num_actors=2) == [
        Segment("demos", 501, 501, pending_inserts=PENDING_INSERTS),
        Segment("transitions", 2500, 500, pending_inserts=0),
    ]


def test_behaviour_scalars_stand_where_the_shared_budget_stood(tmp_path) -> None:
    """With a shared budget an actor's steps are no fixed share of the run: its rows stand
    at the budget's position (`run_steps`), never past the run's end; fixed shares scale
    the actor's own steps."""
    import csv

    from graft.orchestration.summary import log_behaviour_stats
    from service.metrics import MetricsLogger

    logger = MetricsLogger(tmp_path, tensorboard=False)
    shared = [  # 2 actors, 3,000 steps split 2,360 / 640
        {"behaviour_stats": [{"actor_steps": 2360, "run_steps": 2990, "charts/epsilon": 0.1}]},
        {"behaviour_stats": [{"actor_steps": 640, "run_steps": 3000, "charts/epsilon": 0.2}]},
    ]
    log_behaviour_stats(logger, shared, num_actors=2, offset=100)
    log_behaviour_stats(logger, [{"behaviour_stats": [{"actor_steps": 700, "x": 1.0}]}], 2, 0)
    logger.close()
    with (tmp_path / "metrics.csv").open() as f:
        rows = [(int(r["env_steps"]), r["key"]) for r in csv.DictReader(f)]
    assert rows == [
        (3090, "behaviour/charts/epsilon"),
        (3100, "behaviour/charts/epsilon"),
        (1400, "behaviour/x"),
    ]
