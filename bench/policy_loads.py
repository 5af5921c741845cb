"""Benchmark: the CPU a fresh process spends loading a trained run's policy and acting once
(`graft.load_policy`, as `graft eval`, the benchmarks and a user's script do), with the
learner's Adam optimisers built when it first trains (`learner.device.Adam`), against one
that also builds an Adam, as loading the policy did before: building a torch optimiser
imports torch._dynamo.

The run folder is made here: pendulum-td3's learner (256 x 256) after one update, saved
as a run saves it. Each round starts `--loads` fresh interpreters per arm, the arms in turn
(so another job on the machine moves both alike). CPU is the children's (user + system).
The ratio is the figure.

    python bench/policy_loads.py [--loads 5] [--rounds 2]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from learner_updates import random_batch  # bench/, beside this script

from actors.transitions import replay_signature
from graft.config import load_preset
from graft.orchestration.provenance import config_record
from graft.registry import make_builder
from learner.checkpoint import save_checkpoint
from learner.loop import to_tensors

ROOT = Path(__file__).resolve().parents[1]
LOAD = (
    "import sys, graft; policy = graft.load_policy(sys.argv[1]); "
    "obs, _ = policy.make_env().reset(seed=0); policy(obs)"
)
ARMS = {
    "optimisers built when it trains (now)": LOAD,
    "an optimiser built as it loads (before)": LOAD
    + "; import torch; torch.optim.Adam(torch.nn.Linear(2, 2).parameters())",
}


def make_run(folder: Path) -> None:
    """A run folder as `graft train` leaves one: config.yaml and a checkpoint."""
    config = load_preset("pendulum-td3")
    builder = make_builder(config)
    env = config.make_env()
    signature = replay_signature(
        env.observation_space, builder.make_behaviour(num_actors=1).columns()
    )
    env.close()
    batch = random_batch(signature, batch=256, window=1, actions=1, rng=np.random.default_rng(0))
    learner = builder.make_learner()
    learner.update(to_tensors(batch))
    save_checkpoint(folder / "checkpoints", {"algorithm": learner.state_dict()}, updates=1)
    (folder / "config.yaml").write_text(config_record(config))


def children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def load_cpu_s(script: str, run: Path) -> float:
    """CPU seconds of one fresh interpreter running `script` on `run`."""
    before = children_cpu_s()
    subprocess.run([sys.executable, "-c", script, str(run)], check=True, cwd=ROOT)
    return children_cpu_s() - before


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=5, help="fresh processes per arm and round")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        run = Path(folder)
        make_run(run)
        seconds: dict[str, list[float]] = {arm: [] for arm in ARMS}
        for r in range(args.rounds):
            for arm, script in ARMS.items():
                seconds[arm] += [load_cpu_s(script, run) for _ in range(args.loads)]
            print(f"round {r + 1} of {args.rounds} done", flush=True)
    now, before = (statistics.median(s) for s in seconds.values())
    for arm, s in seconds.items():
        print(f"{arm:42s} median {statistics.median(s):.2f} s of CPU per load ({len(s)} loads)")
    print(f"ratio: {now / before:.2f} of the CPU ({before - now:.2f} s less per load)")


if __name__ == "__main__":
    main()
