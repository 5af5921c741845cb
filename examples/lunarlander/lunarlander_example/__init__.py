"""A graft user project: LunarLander-v3 (continuous) and a hard-coded py_trees lander.

graft never imports this package; the presets in ../presets name its parts by import string.
"""
