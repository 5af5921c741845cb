"""Learning: each algorithm (td3, backbone, pretrain, dqn, options) as config, networks, learning
step and builder; the loop that drives an algorithm's phases from replay; checkpoints."""
