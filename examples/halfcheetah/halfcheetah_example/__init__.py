"""A graft user project: MuJoCo's HalfCheetah-v5 and a hand-written py_trees gait.

graft never imports this package; the presets in ../presets name its parts by import string.
"""
