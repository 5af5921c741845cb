"""Run orchestration, the top layer and the only one that imports ``actors`` and ``learner``:
config and presets, the training launcher, the paper's experiments, trained runs, the CLI."""
