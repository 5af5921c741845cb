"""Hierarchical options (sec. III-C): DDQN over {hard-coded, RL}, TD3 with Retrace."""
