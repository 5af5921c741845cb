"""Benchmark: how much return Pendulum-v1's held-out episodes leave above graft's arms.

A controller that knows the dynamics: finite-horizon dynamic programming over the
episode's 200 steps on a grid of (θ, θ̇), then in each state the torque of a finer set
whose one-step model return plus the interpolated value of the next state is highest. It
plays the real environment from its observations, so its score is a return some policy
reaches on those episodes: a lower bound on the best possible, and a measure of the room
left above a learned policy scored on the same episodes (`bench/improve.py`'s, reset seeds
`graft.seeds.held_out_seed(seed) + i`).

    python bench/pendulum_ceiling.py [--first-seed 0] [--seeds 10] [--episodes 50]
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

from graft.seeds import held_out_seed

G, DT, MAX_SPEED, MAX_TORQUE, HORIZON = 10.0, 0.05, 8.0, 2.0, 200
"""Pendulum-v1's constants (gymnasium's classic_control/pendulum.py; m = l = 1)."""


def model_step(theta: np.ndarray, speed: np.ndarray, torque: np.ndarray):
    """Pendulum-v1's step on arrays: (next θ, next θ̇, reward)."""
    angle = (theta + np.pi) % (2 * np.pi) - np.pi
    reward = -(angle**2 + 0.1 * speed**2 + 0.001 * torque**2)
    speed2 = np.clip(speed + (1.5 * G * np.sin(theta) + 3.0 * torque) * DT, -MAX_SPEED, MAX_SPEED)
    return theta + speed2 * DT, speed2, reward


class Grid:
    """Bilinear interpolation on a (θ, θ̇) grid, periodic in θ."""

    def __init__(self, angles: int, speeds: int) -> None:
        self.theta = np.linspace(-np.pi, np.pi, angles, endpoint=False)
        self.speed = np.linspace(-MAX_SPEED, MAX_SPEED, speeds)
        self.shape = (angles, speeds)

    def corners(self, theta: np.ndarray, speed: np.ndarray):
        """Flat indices of the 4 corners around each point and their weights."""
        n, m = self.shape
        x = ((theta + np.pi) % (2 * np.pi)) / (2 * np.pi) * n
        i0 = np.floor(x).astype(np.int64) % n
        fx = x - np.floor(x)
        y = (np.clip(speed, -MAX_SPEED, MAX_SPEED) + MAX_SPEED) / (2 * MAX_SPEED) * (m - 1)
        j0 = np.minimum(np.floor(y).astype(np.int64), m - 2)
        fy = y - j0
        i1 = (i0 + 1) % n
        index = np.stack([i0 * m + j0, i1 * m + j0, i0 * m + j0 + 1, i1 * m + j0 + 1])
        weight = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
        return index, weight


def solve(grid: Grid, torques: np.ndarray) -> np.ndarray:
    """V[t] for t = 0..HORIZON on the grid (V[HORIZON] = 0): the best return from step t."""
    mesh = np.meshgrid(grid.theta, grid.speed, indexing="ij")
    theta, speed = mesh[0].ravel(), mesh[1].ravel()
    steps = [model_step(theta, speed, np.full_like(theta, u)) for u in torques]
    corners = [grid.corners(t2, s2) for t2, s2, _ in steps]
    rewards = np.stack([r for _, _, r in steps])
    values = np.zeros((HORIZON + 1, theta.size))
    for t in range(HORIZON - 1, -1, -1):
        after = np.stack([(values[t + 1][i] * w).sum(0) for i, w in corners])
        values[t, :] = (rewards + after).max(0)
    return values


def act(grid: Grid, value_next: np.ndarray, obs: np.ndarray, torques: np.ndarray) -> float:
    """The torque whose model reward plus the next state's interpolated value is highest."""
    theta2, speed2, reward = model_step(np.arctan2(obs[1], obs[0]), obs[2], torques)
    index, weight = grid.corners(theta2, speed2)
    return float(torques[np.argmax(reward + (value_next[index] * weight).sum(0))])


def play(grid: Grid, values: np.ndarray, seed: int, episodes: int) -> np.ndarray:
    """Returns of the controller on the real environment, episode i reset with seed + i."""
    torques = np.linspace(-MAX_TORQUE, MAX_TORQUE, 81)
    env = gym.make("Pendulum-v1")
    returns = []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        total = 0.0
        for t in range(HORIZON):
            u = act(grid, values[t + 1], obs, torques)
            obs, reward, terminated, truncated, _ = env.step(np.array([u], np.float32))
            total += float(reward)
            if terminated or truncated:
                break
        returns.append(total)
    env.close()
    return np.array(returns)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--seeds", type=int, default=5, help="as bench/improve.py's")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--angles", type=int, default=400)
    parser.add_argument("--speeds", type=int, default=321)
    args = parser.parse_args()
    start = time.perf_counter()
    grid = Grid(args.angles, args.speeds)
    values = solve(grid, np.linspace(-MAX_TORQUE, MAX_TORQUE, 21))
    print(f"value function: {args.angles} x {args.speeds} grid, 21 torques, "
          f"{HORIZON} steps, {time.perf_counter() - start:.0f} s", flush=True)  # fmt: skip
    means = []
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    for seed in seeds:
        returns = play(grid, values, held_out_seed(seed), args.episodes)
        means.append(returns.mean())
        print(f"seed {seed}: {returns.mean():.1f} over {args.episodes} held-out episodes "
              f"(from reset seed {held_out_seed(seed)})", flush=True)  # fmt: skip
    print(f"mean over seeds {seeds.start}-{seeds.stop - 1}: {np.mean(means):.1f}")


if __name__ == "__main__":
    main()
