"""Benchmark: where two arms' Pendulum-v1 policies differ on the held-out episodes.

Each finished run's final greedy policy (`graft.trained.load_behaviour`, as the run's
selection left it) plays the held-out episodes `bench/improve.py` scores it on (reset
seeds `graft.seeds.held_out_seed(seed) + i`), and each episode is split where the
pendulum first comes within 0.3 rad of upright: the swing-up before, the top after. Per
seed it prints both arms' means, how many episodes each wins by more than 1, the return of
each phase, and at the top, after the first 60 steps (balancing, not arriving), the mean
|θ| and |torque| and the share of steps whose torque changes sign.

    python bench/pendulum_where.py RUNS_A RUNS_B [--seeds 0 1 2 3 4] [--episodes 50]

RUNS_A and RUNS_B are run folders with {s} for the seed, e.g.
`runs/v13/pendulum-20k-recipe-uniform-s{s}/pendulum/recipe/s{s}`.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np

from graft.seeds import held_out_seed
from graft.trained import load_behaviour

TOP = np.cos(0.3)
"""cos θ above this: within 0.3 rad of upright."""
FIELDS = (("return", 1), ("swing", 1), ("top", 1), ("angle", 3), ("torque", 2), ("flips", 2))
"""The printed fields, in the header's order, with their decimals."""
SETTLED = 60
"""Steps after which the top counts as balancing (every arm arrives within ~35 on average)."""


def play(
    greedy: Callable[[np.ndarray], np.ndarray], first_reset: int, episodes: int
) -> dict[str, np.ndarray]:
    """Per episode (episode i reset with `first_reset` + i): return, the swing-up's and the
    top's, and the balancing statistics, of a batched greedy policy [B, 3] -> [B, 1]."""
    rows = []
    for i in range(episodes):
        env = gym.make("Pendulum-v1")
        obs, _ = env.reset(seed=first_reset + i)
        swing = top = 0.0
        arrived, angle, torque, flips, previous = False, [], [], [], None
        for t in range(200):
            action = greedy(obs[None].astype(np.float32))[0]
            arrived = arrived or obs[0] > TOP
            if arrived and t >= SETTLED and obs[0] > TOP:
                angle.append(abs(np.arctan2(obs[1], obs[0])))
                torque.append(abs(float(action[0])))
                if previous is not None:
                    flips.append(np.sign(action[0]) != np.sign(previous))
                previous = action[0]
            obs, reward, terminated, truncated, _ = env.step(action)
            if arrived:
                top += reward
            else:
                swing += reward
            if terminated or truncated:
                break
        env.close()
        rows.append(
            (
                swing + top,
                swing,
                top,
                *(np.mean(x) if x else np.nan for x in (angle, torque, flips)),
            )
        )
    return dict(zip([key for key, _ in FIELDS], np.array(rows).T, strict=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs_a")
    parser.add_argument("runs_b")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--episodes", type=int, default=50)
    args = parser.parse_args()
    for runs in (args.runs_a, args.runs_b):
        if "{s}" not in runs:
            parser.error(f"{runs}: put {{s}} where the seed goes in the run folders' path")
        missing = [s for s in args.seeds if not Path(runs.format(s=s)).is_dir()]
        if missing:
            parser.error(f"{runs}: no run folder for seed(s) {missing}")
    print("seed | A, B | A − B | episodes A wins, B wins (by > 1) | swing-up A, B | top A, B"
          " | balancing |θ| A, B | |torque| A, B | sign flips A, B")  # fmt: skip
    for seed in args.seeds:
        a, b = (
            play(load_behaviour(Path(runs.format(s=seed)))[0].greedy, held_out_seed(seed),
                 args.episodes)
            for runs in (args.runs_a, args.runs_b)
        )  # fmt: skip
        d = a["return"] - b["return"]
        pairs = [both(a, b, key, digits) for key, digits in FIELDS]
        print(f"{seed} | {pairs[0]} | {d.mean():+.1f} | {(d > 1).sum()}, {(d < -1).sum()} | "
              + " | ".join(pairs[1:]), flush=True)  # fmt: skip


def both(a: dict[str, np.ndarray], b: dict[str, np.ndarray], key: str, digits: int) -> str:
    """Arm A's and arm B's means of one field, as "A, B"."""
    return f"{np.nanmean(a[key]):.{digits}f}, {np.nanmean(b[key]):.{digits}f}"


if __name__ == "__main__":
    main()
