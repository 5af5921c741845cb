"""``python -m graft.cli``: the `graft` command line."""

from graft.cli import main

main()
