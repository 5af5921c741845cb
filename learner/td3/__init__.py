"""TD3 (Fujimoto et al. 2018), the paper's continuous learner (sec. II-B2), on which the
backbone, pre-training and options algorithms build."""
