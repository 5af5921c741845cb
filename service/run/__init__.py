"""Run orchestration, the top layer and the only one that imports ``actors`` and ``learner``.

Layers inside, each importing only those below it (checked by `lint-imports`): the CLI
(`cli`); the Python API (`api`), tuning (`tuning`) and the paper's experiments
(`experiments`); one training run (`orchestration`) and trained runs (`trained`); the
run's replay server processes (`replay_host`) and the algorithms' builders (`registry`);
config and presets (`config`); placement and validation of values (`placement`,
`validation`).
"""
