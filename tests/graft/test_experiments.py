"""`graft experiment`: seeds run as Ray tasks, results land in a CSV and a PNG."""

from __future__ import annotations

import numpy as np

from graft.experiments.plots import curves
from graft.experiments.runner import read_rows, run_experiment


def test_fig5_two_seeds_in_parallel_writes_csv_and_figure(ray_local, tmp_path):
    tiny = {
        "env_steps": 200,
        "learning_starts": 100,
        "eval_every": 100,
        "eval_episodes": 1,
        "publish_every": 20,
        "num_actors": 1,
        "envs_per_actor": 2,
        "steps_per_insert": 4,
        "slack_env_steps": 16,
        "td3.hidden_sizes": [16, 16],
        "dqn.hidden_sizes": [16, 16],
    }
    csv_path, png_path = run_experiment(
        "fig5", seeds=2, out_dir=tmp_path, parallel=2, overrides=tiny
    )
    rows = read_rows(csv_path)
    assert {r["seed"] for r in rows} == {"0", "1"}
    assert all(np.isfinite(float(r["return_mean"])) for r in rows)
    # The evaluator reports how often the greedy policy over options picked the RL option.
    assert all(0.0 <= float(r["options/rl_fraction"]) <= 1.0 for r in rows)
    c = curves(rows, "options")
    assert c["seeds"] == 2 and len(c["mean"]) >= 2
    assert png_path.stat().st_size > 0
