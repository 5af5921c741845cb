"""How the launcher splits phases among actors, and how their inserts go out: a table
whose rate limiter holds samples per insert has every insert waited for (the limiter
paces acting); a table that never holds inserts gets a queue of background inserts."""

from __future__ import annotations

from actors.env_actor import Segment
from learner.agent import Phase
from service.run.launcher import PENDING_INSERTS, _segments


def test_rate_limited_phases_wait_for_each_insert() -> None:
    demos = Phase("demos", env_steps=1001, updates=0, min_size=100, warmup_steps=1001)
    online = Phase(
        "transitions", env_steps=5000, updates=4000, min_size=1000, samples_per_insert=256.0,
        warmup_steps=1000,
    )  # fmt: skip
    empty = Phase("pretrain", env_steps=0, updates=500, min_size=1)
    assert _segments([demos, empty, online], num_actors=2) == [
        Segment("demos", 501, 501, pending_inserts=PENDING_INSERTS),
        Segment("transitions", 2500, 500, pending_inserts=0),
    ]
