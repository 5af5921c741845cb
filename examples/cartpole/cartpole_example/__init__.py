"""A graft user project with discrete actions: CartPole-v1 and a hard-coded balancing tree.

graft never imports this package; the presets in ../presets name its parts by import string.
"""
