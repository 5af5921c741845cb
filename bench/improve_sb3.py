"""stable-baselines3 from scratch: the outside reference arms of `bench/improve.py`.

RL without the tree as a user would reach for it: stable-baselines3's TD3 and SAC on a
continuous task, its DQN on a discrete one (arms ``sb3-td3``, ``sb3-sac``, ``sb3-dqn``),
with rl-baselines3-zoo's hyper-parameters for the task where the zoo has them
(`HYPERPARAMETERS`, each with its source). Each arm runs on the task preset's
environment (its env_id, env_kwargs and obs_wrapper), with the same env-step budget and
seeds as graft's arms, and is scored on the same 50 held-out episodes: episode i of seed
S reset with ``100,000 + 1,000·S + i`` (`graft.seeds.held_out_seed`), deterministic
actions. Its training environment first resets from the seed's training range and its
in-run evaluations (every ``eval_every`` env steps of the preset) play the preset's
``eval_episodes`` episodes from the evaluation range, as graft's runs do.

Each seed is one process, which writes into RUN (``OUT/TASK/ARM/sS``) its final model
(``model.zip``), ``summary.json`` (the in-run evaluations, the settings and their source,
the versions) and, last, ``eval.json`` (the held-out returns); a seed whose
``eval.json`` exists is read back, not re-run:

    python -m bench.improve --task pendulum --arm sb3-td3 --arm sb3-sac --seeds 2 \\
        --env-steps 30000 --out runs/sb3
    python -m bench.improve_sb3 --task pendulum --preset bench/tasks/pendulum.yaml \\
        --arm sb3-sac --seed 0 --run-dir RUN --env-steps 30000   # one seed, as run there

stable-baselines3 is a bench-only extra (``pip install -e '.[bench]'``, which `make
setup` does); graft itself never imports it.
"""

from __future__ import annotations

import argparse
import copy
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np

import graft
from bench.improve_report import REFERENCE_ARMS, SeedRow, summarise, worst_drop
from graft.api import Policy
from graft.config import load_preset
from graft.seeds import evaluation_seed, held_out_seed, training_seed

ALGORITHMS = {"sb3-td3": "TD3", "sb3-sac": "SAC", "sb3-dqn": "DQN"}
"""Arm -> the stable-baselines3 class it trains (the arms are `REFERENCE_ARMS`)."""
SB3_ARMS = tuple(REFERENCE_ARMS)
_ZOO = "rl-baselines3-zoo hyperparams"
_TD3_ZOO = f"{_ZOO}/td3.yml@a02f4fb"
_SAC_ZOO = f"{_ZOO}/sac.yml@c94924e"
_DQN_ZOO = f"{_ZOO}/dqn.yml@ce95481"
_NET = {"policy_kwargs": {"net_arch": [400, 300]}}
_TD3_EPISODIC = {
    "gamma": 0.98,
    "buffer_size": 200_000,
    "learning_starts": 10_000,
    "noise_std": 0.1,
    "gradient_steps": -1,
    "train_freq": [1, "episode"],
    "learning_rate": 1e-3,
    **_NET,
}
"""The zoo's TD3 for Pendulum and LunarLanderContinuous: an episode's worth of updates
after each episode (gradient_steps -1), normal exploration noise σ 0.1."""
_DQN_LANDER = {
    "learning_rate": 6.3e-4,
    "batch_size": 128,
    "buffer_size": 50_000,
    "learning_starts": 0,
    "gamma": 0.99,
    "target_update_interval": 250,
    "train_freq": 4,
    "gradient_steps": -1,
    "exploration_fraction": 0.12,
    "exploration_final_eps": 0.1,
    "policy_kwargs": {"net_arch": [256, 256]},
}
_MUJOCO_TD3 = {"learning_starts": 10_000, "noise_std": 0.1}
_MUJOCO_TD3_SOURCE = (
    "stable-baselines3 defaults with 10,000 random steps first and normal noise σ 0.1 (the "
    f"zoo's MuJoCo SAC start, {_SAC_ZOO} HalfCheetah-v3; graft's from-scratch TD3 on the task)"
)
_MUJOCO_SAC = {"learning_starts": 10_000}
HYPERPARAMETERS: dict[tuple[str, str], tuple[Mapping[str, Any], str]] = {
    ("pendulum", "sb3-td3"): (_TD3_EPISODIC, f"{_TD3_ZOO} Pendulum-v0"),
    ("pendulum", "sb3-sac"): ({"learning_rate": 1e-3}, f"{_SAC_ZOO} Pendulum-v1"),
    ("lunarlander", "sb3-td3"): (_TD3_EPISODIC, f"{_TD3_ZOO} LunarLanderContinuous-v2"),
    ("lunarlander", "sb3-sac"): (
        {"batch_size": 256, "learning_rate": "lin_7.3e-4", "buffer_size": 1_000_000,
         "ent_coef": "auto", "gamma": 0.99, "tau": 0.01, "train_freq": 1, "gradient_steps": 1,
         "learning_starts": 10_000, **_NET},
        f"{_SAC_ZOO} LunarLanderContinuous-v2",
    ),  # fmt: skip
    ("mountaincar", "sb3-td3"): ({"ou_noise_std": 0.5}, f"{_TD3_ZOO} MountainCarContinuous-v0"),
    ("mountaincar", "sb3-sac"): (
        {"learning_rate": 3e-4, "buffer_size": 50_000, "batch_size": 512, "ent_coef": 0.1,
         "train_freq": 32, "gradient_steps": 32, "gamma": 0.9999, "tau": 0.01,
         "learning_starts": 0, "use_sde": True,
         "policy_kwargs": {"log_std_init": -3.67, "net_arch": [64, 64]}},
        f"{_SAC_ZOO} MountainCarContinuous-v0",
    ),  # fmt: skip
    ("cartpole", "sb3-dqn"): (
        {"learning_rate": 2.3e-3, "batch_size": 64, "buffer_size": 100_000,
         "learning_starts": 1000, "gamma": 0.99, "target_update_interval": 10,
         "train_freq": 256, "gradient_steps": 128, "exploration_fraction": 0.16,
         "exploration_final_eps": 0.04, "policy_kwargs": {"net_arch": [256, 256]}},
        f"{_DQN_ZOO} CartPole-v1",
    ),  # fmt: skip
    ("acrobot", "sb3-dqn"): (_DQN_LANDER, f"{_DQN_ZOO} Acrobot-v1"),
    ("lunarlander-discrete", "sb3-dqn"): (_DQN_LANDER, f"{_DQN_ZOO} LunarLander-v2"),
    ("halfcheetah", "sb3-sac"): (_MUJOCO_SAC, f"{_SAC_ZOO} HalfCheetah-v3"),
    ("hopper", "sb3-sac"): (_MUJOCO_SAC, f"{_SAC_ZOO} Hopper-v3"),
    ("walker2d", "sb3-sac"): (_MUJOCO_SAC, f"{_SAC_ZOO} Walker2d-v3"),
    ("reacher", "sb3-sac"): (_MUJOCO_SAC, f"{_SAC_ZOO} HalfCheetah-v3's (no Reacher entry)"),
    **{(t, "sb3-td3"): (_MUJOCO_TD3, _MUJOCO_TD3_SOURCE)
       for t in ("halfcheetah", "hopper", "walker2d", "reacher")},
}  # fmt: skip
"""(task, arm) -> stable-baselines3 settings and where they come from; a setting not
named is stable-baselines3's default. ``noise_std`` (``ou_noise_std``) is Gaussian
(Ornstein-Uhlenbeck) exploration noise of that σ on every action dimension; ``lin_X`` a
learning rate decayed linearly from X to 0. The zoo's exploration fraction is of the
budget trained here."""


def require() -> None:
    """Exits with one line when stable-baselines3 is not installed."""
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        raise SystemExit(
            "the sb3-* arms need stable-baselines3, a bench-only extra: "
            "pip install -e '.[bench]' (make setup installs it)"
        ) from None


def arms_of(task: str) -> list[str]:
    """The stable-baselines3 arms that `task` has settings for."""
    return [arm for t, arm in HYPERPARAMETERS if t == task]


def build(arm: str, settings: Mapping[str, Any], env: Any, *, seed: int) -> Any:
    """The arm's stable-baselines3 model on `env`, seeded with `seed` (torch, NumPy and
    the action space), on the CPU."""
    import stable_baselines3
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    kwargs = copy.deepcopy(dict(settings))  # stable-baselines3 writes into policy_kwargs
    size = int(np.prod(env.action_space.shape or (1,)))
    if "noise_std" in kwargs:
        sigma = kwargs.pop("noise_std") * np.ones(size)
        kwargs["action_noise"] = NormalActionNoise(np.zeros(size), sigma)
    if "ou_noise_std" in kwargs:
        sigma = kwargs.pop("ou_noise_std") * np.ones(size)
        kwargs["action_noise"] = OrnsteinUhlenbeckActionNoise(np.zeros(size), sigma)
    rate = kwargs.get("learning_rate")
    if isinstance(rate, str) and rate.startswith("lin_"):
        start = float(rate[4:])
        kwargs["learning_rate"] = lambda remaining: remaining * start  # remaining: 1 → 0
    if isinstance(kwargs.get("train_freq"), list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    algorithm = getattr(stable_baselines3, ALGORITHMS[arm])
    return algorithm("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **kwargs)


def acting(model: Any) -> Callable[[np.ndarray], np.ndarray]:
    """The model's deterministic policy, batched ``[B, *obs] -> [B, *action]`` (SAC: its
    mean action; DQN: argmax Q)."""

    def act(observations: np.ndarray) -> np.ndarray:
        actions, _ = model.predict(observations, deterministic=True)
        return np.asarray(actions)

    return act


@dataclass(frozen=True)
class Plan:
    """What one seed's process trains and where it writes."""

    task: str
    arm: str
    preset: Path
    seed: int
    run_dir: Path
    env_steps: Optional[int]
    episodes: int
    eval_every: Optional[int] = None
    eval_episodes: Optional[int] = None
    """In-run evaluations: the preset's when None."""
    threads: int = 1


def train(plan: Plan) -> dict[str, Any]:
    """Trains one seed with in-run evaluations, saves the model, scores it on the held-out
    episodes; writes summary.json, then eval.json, and returns the latter."""
    import stable_baselines3
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    torch.set_num_threads(plan.threads)
    config = load_preset(plan.preset, **({"env_steps": plan.env_steps} if plan.env_steps else {}))
    spec = config.env_spec()
    every = plan.eval_every or config.eval_every
    n_eval = plan.eval_episodes or config.eval_episodes
    steps: list[int] = []
    means: list[float] = []

    class InRun(BaseCallback):  # type: ignore[misc]  # untyped base
        def _on_step(self) -> bool:
            if self.num_timesteps % every == 0:
                played = graft.evaluate(
                    acting(self.model), env=spec, episodes=n_eval, seed=evaluation_seed(plan.seed)
                )
                steps.append(int(self.num_timesteps))
                means.append(float(played.mean))
            return True

    settings, source = HYPERPARAMETERS[(plan.task, plan.arm)]
    model = build(plan.arm, settings, spec.make(), seed=plan.seed)
    model.env.seed(training_seed(plan.seed, 0))  # its first reset: the training range
    start = time.perf_counter()
    model.learn(total_timesteps=config.env_steps, callback=InRun())
    wall_s = time.perf_counter() - start
    plan.run_dir.mkdir(parents=True, exist_ok=True)
    model.save(plan.run_dir / "model.zip")
    summary = {
        "task": plan.task, "arm": plan.arm, "algorithm": f"sb3 {ALGORITHMS[plan.arm]}",
        "env_id": spec.env_id, "seed": plan.seed, "env_steps": int(model.num_timesteps),
        "wall_s": wall_s, "settings": dict(settings), "source": source,
        "evaluations": {"env_steps": steps, "return_mean": means, "episodes": n_eval,
                        "seed": evaluation_seed(plan.seed)},
        "training_seed": training_seed(plan.seed, 0), "threads": plan.threads,
        "stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__,
    }  # fmt: skip
    (plan.run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    final = graft.evaluate(
        acting(model), env=spec, episodes=plan.episodes, seed=held_out_seed(plan.seed)
    )
    saved = {
        "mean": float(final.mean), "std": float(np.std(final.returns)),
        "returns": [float(r) for r in final.returns], "episodes": plan.episodes,
        "seed": held_out_seed(plan.seed), "wall_s": wall_s,
    }  # fmt: skip
    (plan.run_dir / "eval.json").write_text(json.dumps(saved))
    return saved


def run_seed(plan: Plan) -> dict[str, Any]:
    """One seed in its own process (`python -m bench.improve_sb3`, its output in
    RUN.log), or its eval.json read back when it finished before; that eval.json."""
    done = plan.run_dir / "eval.json"
    if done.exists():
        return dict(json.loads(done.read_text()))
    shutil.rmtree(plan.run_dir, ignore_errors=True)  # an interrupted run starts afresh
    plan.run_dir.parent.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "bench.improve_sb3", "--task", plan.task, "--arm", plan.arm]
    command += ["--preset", str(plan.preset), "--seed", str(plan.seed)]
    command += ["--run-dir", str(plan.run_dir), "--episodes", str(plan.episodes)]
    command += ["--threads", str(plan.threads)]
    for flag, value in (
        ("--env-steps", plan.env_steps),
        ("--eval-every", plan.eval_every),
        ("--eval-episodes", plan.eval_episodes),
    ):
        if value is not None:
            command += [flag, str(value)]
    with open(plan.run_dir.parent / f"{plan.run_dir.name}.log", "w") as log:
        subprocess.run(command, check=True, stdout=log, stderr=subprocess.STDOUT)
    return dict(json.loads(done.read_text()))


def score(plan: Plan, saved: Mapping[str, Any], tree: Policy) -> SeedRow:
    """A finished seed's row, with the tree on the same held-out and in-run episodes."""
    summary = json.loads((plan.run_dir / "summary.json").read_text())
    evaluations = summary["evaluations"]
    return SeedRow(
        seed=plan.seed,
        tree=graft.evaluate(tree, episodes=plan.episodes, seed=held_out_seed(plan.seed)).mean,
        final=float(saved["mean"]),
        tree_in_run=graft.evaluate(
            tree, episodes=int(evaluations["episodes"]), seed=int(evaluations["seed"])
        ).mean,
        steps=[int(s) for s in evaluations["env_steps"]],
        evaluations=[float(m) for m in evaluations["return_mean"]],
        env_steps=int(summary["env_steps"]),
        wall_s=float(summary["wall_s"]),
    )


def run_arm(
    task: str, arm: str, *, preset: Path, seeds: Sequence[int], out: Path,
    env_steps: Optional[int], episodes: int, in_run: tuple[Optional[int], Optional[int]],
) -> tuple[dict[str, Any], list[SeedRow]]:  # fmt: skip
    """Trains (or reads back) and scores every seed of one stable-baselines3 arm of one
    task into OUT/TASK/ARM/sS; its summary and seed rows, as `bench.improve.run_task`'s.
    ``in_run``: the in-run evaluations' (eval_every, eval_episodes), the preset's when None."""
    config = load_preset(preset, **({"env_steps": env_steps} if env_steps else {}))
    tree = graft.load_policy("hardcoded", preset=preset)
    rows: list[SeedRow] = []
    for seed in seeds:
        run_dir = out / task / arm / f"s{seed}"
        plan = Plan(task, arm, preset, seed, run_dir, env_steps, episodes, *in_run)
        try:
            saved = run_seed(plan)
        except subprocess.CalledProcessError:  # reported and left out; the others go on
            print(f"{task} {arm} seed {seed}: FAILED, see {run_dir}.log", flush=True)
            continue
        row = score(plan, saved, tree)
        rows.append(row)
        print(
            f"{task} {arm} seed {seed}: tree {row.tree:.1f}, final {row.final:.1f} "
            f"({row.improvement:+.1f}); worst in-run evaluation "
            f"{100 * worst_drop(row, config.env_steps):+.0f} % of |tree|; {row.env_steps} "
            f"env steps, {row.wall_s:.0f} s",
            flush=True,
        )
    if not rows:
        raise SystemExit(f"{task} {arm}: every seed failed (logs in {out / task / arm})")
    algorithm = f"sb3 {ALGORITHMS[arm]}"
    summary = summarise(task, rows, budget=config.env_steps, algorithm=algorithm)
    return {**summary, "arm": arm}, rows


def main(argv: Optional[Sequence[str]] = None) -> None:
    parser = argparse.ArgumentParser(description="One seed of a stable-baselines3 arm.")
    parser.add_argument("--task", required=True)
    parser.add_argument("--arm", required=True, choices=SB3_ARMS)
    parser.add_argument("--preset", required=True, type=Path)
    parser.add_argument("--seed", required=True, type=int)
    parser.add_argument("--run-dir", required=True, type=Path)
    parser.add_argument("--env-steps", type=int)
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--eval-every", type=int)
    parser.add_argument("--eval-episodes", type=int)
    parser.add_argument("--threads", type=int, default=1, help="torch's CPU threads")
    args = parser.parse_args(argv)
    if (args.task, args.arm) not in HYPERPARAMETERS:
        parser.error(f"--arm {args.arm}: no settings for task {args.task} ({arms_of(args.task)})")
    require()
    plan = Plan(**{k: v for k, v in vars(args).items()})
    saved = train(plan)
    print(f"{plan.task} {plan.arm} seed {plan.seed}: {saved['mean']:.1f} held out", flush=True)


if __name__ == "__main__":
    main()
