"""``python -m service.run.cli``: the `graft` command line."""

from service.run.cli import main

main()
