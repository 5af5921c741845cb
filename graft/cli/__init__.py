"""The `graft` command line: presets, train, eval, experiment, tune, replay, minecraft.

Each command group is a module of its own (`train`, `evaluate`, `studies`, `replay`);
`parser` puts them together. Each replay server's process runs
``python -m graft.cli.replay``, which loads this package first, so it imports no
command module itself.
"""

from __future__ import annotations

from typing import Optional


def main(argv: Optional[list[str]] = None) -> None:
    """The `graft` console script: parses `argv` (default sys.argv) and runs its command."""
    from graft.cli.parser import main as run_command

    run_command(argv)
