"""A graft user project: MountainCarContinuous-v0 and a hard-coded energy-pumping tree.

graft never imports this package; the presets in ../presets name its parts by import string.
"""
