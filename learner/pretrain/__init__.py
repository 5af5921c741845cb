"""TD3 pre-trained from hard-coded demonstrations (sec. III-A, figs 2-3), TD3+BC, burn-in."""
