"""Double DQN (van Hasselt et al. 2016), the paper's discrete learner (sec. II-B1)."""
