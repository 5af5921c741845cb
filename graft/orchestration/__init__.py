"""One training run, end to end: Ray, its roles (replay servers, actors, evaluator,
learner), their supervision and step budget, lock-step mode, pre-flight checks, resume and
the run folder's summary; the same run inside a remote cluster (`on_cluster`)."""
