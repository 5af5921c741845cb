"""Benchmark: updates/s of each algorithm's learner on one device, eager and compiled.

Each row builds a preset's learner as `graft train` does (`make_learner(device=...,
compile=...)`), feeds it sampled-shaped batches (numpy columns of the preset's replay
signature, turned into tensors on the device the way the learner loop does it) and
counts its updates for `--seconds`. Beside them, in the same process, a minimal TD3 step
in plain torch at Pendulum shapes (batch 256, 256 x 256 networks), with no replay
columns, counters or metrics, fed as the learners are; and on CUDA the ceiling: that step
captured whole, one CUDA graph per delay cycle, its batch already on the device (on the
CPU it is skipped, with the reason printed). Each row's ``vs_ceiling`` is its rate over
the ceiling's (over the plain-torch row's where there is no ceiling). Writes
``learner.csv`` to `--out`; prints a table.

    python bench/learner_updates.py [--device cpu] [--seconds 10] [--compile off,compile]
        [--learners td3,ddqn] [--compiled-learners td3]
    python bench/learner_updates.py --device cuda --compile off,captured
"""

# ruff: noqa: E402 (the folder fix below must run before graft's packages are imported)
from __future__ import annotations

import sys
from pathlib import Path

# Run as a script, this folder comes first on sys.path, and `learner` would be this file.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != Path(__file__).resolve().parent]

import argparse
import copy
import csv
import tempfile
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from actors.transitions import replay_signature
from graft.config import TrainConfig, load_preset
from graft.registry import make_builder
from learner.checkpoint import save_checkpoint
from learner.device import (
    Adam,
    BatchFeed,
    device_name,
    resolve_compile,
    resolve_device,
)
from learner.feed import make_feed
from learner.loop import to_tensors
from learner.td3.learning import TD3Learner
from service.core import Columns

PRESETS = {
    "td3": "pendulum-td3",
    "pretrain_td3 (demos)": "pendulum-pretrained-td3",
    "backbone_td3": "pendulum-backbone",
    "backbone_td3 + teacher": "pendulum-backbone-teacher",
    "ddqn": "cartpole-ddqn",
    "options": "pendulum-options-residual",
}
"""Row name -> the preset whose learner it times (its first phase's step)."""
POOL = 16
"""Distinct batches cycled through (a fresh copy to the device each update)."""


def random_batch(
    signature: dict[str, Any], *, batch: int, window: int, actions: int, rng: np.random.Generator
) -> Columns:
    """A batch of the signature's columns, [B] (or [B, window]) + column shape, with values
    an update accepts: discrete actions below `actions`, one option per window whose steps
    count from a random start, no terminal state but a window's last step."""
    lead = (batch,) if window == 1 else (batch, window)
    columns: dict[str, np.ndarray] = {}
    for name, spec in signature.items():
        shape = lead + tuple(spec["shape"])
        dtype = np.dtype(spec["dtype"])
        if name == "action" and dtype.kind == "i":
            columns[name] = rng.integers(0, actions, size=shape)
        elif name == "option":
            columns[name] = np.repeat(rng.integers(0, 2, size=(batch, 1)), window, axis=1)
        elif name == "option_step":
            columns[name] = (rng.integers(0, window, size=(batch, 1)) + np.arange(window)) % window
        elif name == "terminated":
            done = rng.random(shape) < 0.05
            if window > 1:  # only a window's last step may end its episode
                done[:, :-1] = False
            columns[name] = done
        elif dtype.kind == "b":
            columns[name] = np.zeros(shape, bool)
        elif dtype.kind == "i":
            columns[name] = np.zeros(shape, dtype)
        else:
            columns[name] = rng.normal(size=shape).astype(dtype)
    return columns


def _teacher(folder: Path, config: TrainConfig) -> str:
    """An untrained TD3 checkpoint of the preset's shapes, standing in for a teacher run."""
    learner = TD3Learner(
        3, 1, np.array([-2.0]), np.array([2.0]), config=config.td3, seed=config.seed
    )
    save_checkpoint(folder / "checkpoints", {"algorithm": learner.state_dict()}, updates=0)
    hidden = ", ".join(str(h) for h in config.td3.hidden_sizes)
    (folder / "config.yaml").write_text(f"td3:\n  hidden_sizes: [{hidden}]\n")
    return str(folder)


def timed(
    step: Callable[[], Any], *, seconds: float, device: torch.device, warmup: int
) -> tuple[float, float]:
    """(seconds of the first `warmup` steps (compiling happens there), steps/s after them)."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    start = time.perf_counter()
    for _ in range(warmup):
        step()
    sync()
    warm = time.perf_counter() - start
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for _ in range(10):
            step()
        steps += 10
    sync()
    return warm, steps / (time.perf_counter() - start)


def learner_row(
    name: str, preset: str, *, device: torch.device, compile: str, seconds: float, tmp: Path
) -> dict[str, Any]:
    """One algorithm's learner, timed on `device` with `compile`."""
    overrides = {}
    if preset == "pendulum-backbone-teacher":
        overrides["backbone.teacher"] = _teacher(tmp / "teacher", load_preset(preset))
    config = load_preset(preset, **overrides)
    builder = make_builder(config)
    mode = resolve_compile(compile, device)
    learner = builder.make_learner(device=device, compile=mode)
    phase = builder.phases()[0]
    env = config.make_env()
    signature = replay_signature(
        env.observation_space, builder.make_behaviour(num_actors=1).columns()
    )
    env.close()
    rng = np.random.default_rng(0)
    actions = getattr(builder, "num_actions", 2)
    pool = [
        random_batch(
            signature,
            batch=builder.batch_size,
            window=phase.sequence_length,
            actions=actions,
            rng=rng,
        )
        for _ in range(POOL)
    ]
    drawn = iter(range(10**12))
    feed = make_feed(
        lambda: pool[next(drawn) % POOL],
        device=device,
        depth=2,
        to_tensors=to_tensors,
        packed=mode == "captured",
    )

    def step() -> None:
        _, batch = feed.next(left=2**62)
        phase.step(learner, batch)

    warm, rate = timed(step, seconds=seconds, device=device, warmup=20)
    return {
        "learner": name,
        "preset": preset,
        "batch": builder.batch_size,
        "window": phase.sequence_length,
        "compile": mode,
        "updates_per_s": round(rate, 1),
        "warmup_s": round(warm, 1),
    }


class _Actor(nn.Module):
    def __init__(self, obs: int, act: int, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(obs, hidden),
            nn.ReLU(),
            nn.Linear(hidden, hidden),
            nn.ReLU(),
            nn.Linear(hidden, act),
            nn.Tanh(),
        )

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return 2.0 * self.net(obs)


class _Critic(nn.Module):
    def __init__(self, obs: int, act: int, hidden: int) -> None:
        super().__init__()
        self.q = nn.ModuleList(
            nn.Sequential(
                nn.Linear(obs + act, hidden),
                nn.ReLU(),
                nn.Linear(hidden, hidden),
                nn.ReLU(),
                nn.Linear(hidden, 1),
            )
            for _ in range(2)
        )

    def forward(self, obs: torch.Tensor, act: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([obs, act], dim=-1)
        return self.q[0](x).squeeze(-1), self.q[1](x).squeeze(-1)


def ceiling_row(*, device: torch.device, seconds: float) -> dict[str, Any]:
    """A minimal TD3 step in plain torch (CleanRL's shape): Pendulum, batch 256, 256 x 256."""
    obs_dim, act_dim, hidden, batch = 3, 1, 256, 256
    torch.manual_seed(0)
    actor, critic = _Actor(obs_dim, act_dim, hidden).to(device), _Critic(obs_dim, act_dim, hidden)
    critic.to(device)
    actor_t, critic_t = copy.deepcopy(actor), copy.deepcopy(critic)
    actor_opt = Adam(actor.parameters(), lr=3e-4, device=device)
    critic_opt = Adam(critic.parameters(), lr=3e-4, device=device)
    rng = np.random.default_rng(0)
    pool = [
        {
            "obs": rng.normal(size=(batch, obs_dim)).astype(np.float32),
            "action": rng.normal(size=(batch, act_dim)).astype(np.float32),
            "reward": rng.normal(size=batch).astype(np.float32),
            "terminated": np.zeros(batch, bool),
            "next_obs": rng.normal(size=(batch, obs_dim)).astype(np.float32),
        }
        for _ in range(POOL)
    ]
    drawn = iter(range(10**12))
    feed = BatchFeed(
        lambda: pool[next(drawn) % POOL], device=device, depth=2, to_tensors=to_tensors
    )
    count = [0]

    def step() -> None:
        _, b = feed.next(left=2**62)
        with torch.no_grad():
            noise = (torch.randn_like(b["action"]) * 0.4).clamp(-1.0, 1.0)
            next_action = (actor_t(b["next_obs"]) + noise).clamp(-2.0, 2.0)
            q1_t, q2_t = critic_t(b["next_obs"], next_action)
            y = b["reward"] + 0.99 * (1.0 - b["terminated"].float()) * torch.min(q1_t, q2_t)
        q1, q2 = critic(b["obs"], b["action"])
        loss = F.mse_loss(q1, y) + F.mse_loss(q2, y)
        critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        critic_opt.step()
        count[0] += 1
        if count[0] % 2 == 0:
            actor_loss = -critic(b["obs"], actor(b["obs"]))[0].mean()
            actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward()
            actor_opt.step()
            with torch.no_grad():
                for target, source in ((actor_t, actor), (critic_t, critic)):
                    torch._foreach_lerp_(
                        list(target.parameters()), list(source.parameters()), 0.005
                    )

    warm, rate = timed(step, seconds=seconds, device=device, warmup=20)
    return {
        "learner": "plain-torch TD3 step",
        "preset": "-",
        "batch": batch,
        "window": 1,
        "compile": "off",
        "updates_per_s": round(rate, 1),
        "warmup_s": round(warm, 1),
    }


def captured_ceiling_row(*, device: torch.device, seconds: float) -> dict[str, Any]:
    """The ceiling: the plain-torch TD3 step captured whole, one CUDA graph per delay cycle
    of 2 updates (capturable fused Adam, the batch already on the device)."""
    obs_dim, act_dim, hidden, batch = 3, 1, 256, 256
    torch.manual_seed(0)
    actor, critic = _Actor(obs_dim, act_dim, hidden).to(device), _Critic(obs_dim, act_dim, hidden)
    critic.to(device)
    actor_t, critic_t = copy.deepcopy(actor), copy.deepcopy(critic)
    lr = torch.tensor(3e-4, device=device)
    actor_opt = torch.optim.Adam(actor.parameters(), lr=lr, capturable=True, fused=True)
    critic_opt = torch.optim.Adam(critic.parameters(), lr=lr, capturable=True, fused=True)
    b = {
        "obs": torch.randn(batch, obs_dim, device=device),
        "action": torch.randn(batch, act_dim, device=device),
        "reward": torch.randn(batch, device=device),
        "done": torch.zeros(batch, device=device),
        "next_obs": torch.randn(batch, obs_dim, device=device),
    }

    def critic_step() -> None:
        with torch.no_grad():
            noise = (torch.randn_like(b["action"]) * 0.4).clamp(-1.0, 1.0)
            next_action = (actor_t(b["next_obs"]) + noise).clamp(-2.0, 2.0)
            y = b["reward"] + 0.99 * (1.0 - b["done"]) * torch.min(
                *critic_t(b["next_obs"], next_action)
            )
        q1, q2 = critic(b["obs"], b["action"])
        critic_opt.zero_grad(set_to_none=False)
        (F.mse_loss(q1, y) + F.mse_loss(q2, y)).backward()
        critic_opt.step()

    def cycle() -> None:
        critic_step()
        critic_step()
        actor_opt.zero_grad(set_to_none=False)
        (-critic(b["obs"], actor(b["obs"]))[0].mean()).backward()
        actor_opt.step()
        with torch.no_grad():
            for target, source in ((actor_t, actor), (critic_t, critic)):
                torch._foreach_lerp_(list(target.parameters()), list(source.parameters()), 0.005)

    side = torch.cuda.Stream(device)
    side.wait_stream(torch.cuda.current_stream(device))
    with torch.cuda.stream(side):
        for _ in range(3):  # warm-up: the optimisers' state, cuBLAS's handles
            cycle()
    torch.cuda.current_stream(device).wait_stream(side)
    graph = torch.cuda.CUDAGraph()
    with torch.cuda.graph(graph):
        cycle()
    warm, rate = timed(graph.replay, seconds=seconds, device=device, warmup=20)
    return {
        "learner": "TD3 step captured whole (ceiling)",
        "preset": "-",
        "batch": batch,
        "window": 1,
        "compile": "cuda graph",
        "updates_per_s": round(2 * rate, 1),
        "warmup_s": round(warm, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cpu", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--seconds", type=float, default=10.0, help="timed per row")
    parser.add_argument(
        "--compile",
        default="off,compile",
        help="comma-separated learner.compile modes per algorithm (off, compile, cuda_graphs, "
        "captured)",
    )
    parser.add_argument(
        "--learners",
        default=",".join(PRESETS),
        help=f"comma-separated rows among: {', '.join(PRESETS)}",
    )
    parser.add_argument(
        "--compiled-learners",
        default=None,
        help="rows that get the modes other than off (default: every row in --learners)",
    )
    parser.add_argument("--threads", type=int, default=1, help="torch threads (as graft train)")
    parser.add_argument("--out", type=Path, default=Path("runs/bench-learner"))
    args = parser.parse_args()

    torch.set_num_threads(args.threads)
    device = resolve_device(args.device)
    names = [n.strip() for n in args.learners.split(",") if n.strip()]
    unknown = [n for n in names if n not in PRESETS]
    if unknown:
        parser.error(f"--learners: unknown {unknown}; choose from {', '.join(PRESETS)}")
    modes = [m.strip() for m in args.compile.split(",") if m.strip()]
    compiled = names if args.compiled_learners is None else args.compiled_learners.split(",")
    where = f"{device} ({device_name(device)}), {args.threads} torch thread(s)"
    print(f"learner updates/s on {where}, {args.seconds:g} s per row", flush=True)
    rows = [ceiling_row(device=device, seconds=args.seconds)]
    print(rows[-1], flush=True)
    if device.type == "cuda":
        rows.insert(0, captured_ceiling_row(device=device, seconds=args.seconds))
        print(rows[0], flush=True)
    else:
        print("ceiling row skipped: a CUDA graph needs a CUDA device, this run is on the CPU")
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for mode in modes:
                if mode != "off" and name not in compiled:
                    continue
                rows.append(
                    learner_row(
                        name,
                        PRESETS[name],
                        device=device,
                        compile=mode,
                        seconds=args.seconds,
                        tmp=Path(tmp),
                    )
                )
                print(rows[-1], flush=True)
    ceiling = rows[0]["updates_per_s"]
    for row in rows:
        row["device"] = str(device)
        row["vs_ceiling"] = round(row["updates_per_s"] / ceiling, 2)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "learner.csv"
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    print(f"\n{where}")
    print("| learner | preset | batch × window | compile | updates/s | × ceiling | warm-up s |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['learner']} | {r['preset']} | {r['batch']} × {r['window']} | {r['compile']} "
            f"| {r['updates_per_s']} | {r['vs_ceiling']} | {r['warmup_s']} |"
        )
    print(f"results: {path}")


if __name__ == "__main__":
    main()
