"""graft's Python API: train a preset on your own task, load the policy, evaluate it.

    import graft
    run = graft.train("path/to/task.yaml", env_steps=20_000)
    policy = graft.load_policy(run.run_dir)
    graft.evaluate(policy, episodes=20).mean

A thin facade over ``service.run.api``, which the ``graft`` command line calls too.
"""

from service import __version__
from service.run.api import Evaluation, Policy, Run, evaluate, load_policy, train
from service.run.config import TrainConfig, load_preset

__all__ = [
    "Evaluation",
    "Policy",
    "Run",
    "TrainConfig",
    "__version__",
    "evaluate",
    "load_policy",
    "load_preset",
    "train",
]
