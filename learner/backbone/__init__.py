"""Backbone TD3 (sec. III-B): the hard-coded policy acts, TD3 learns a clipped correction."""
