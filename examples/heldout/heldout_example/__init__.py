"""graft's held-out tasks: four environments and their hand-written trees, written and
scored before any graft run on them, so that the default recipe is measured on tasks it
was not tuned on (bench/improve.py --suite heldout).

graft never imports this package; the presets in ../presets name its trees by import string.
"""
