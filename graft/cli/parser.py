"""The `graft` command line: presets, train, eval, experiment, replay, minecraft.

A bad value is one line on stderr naming the field, the value and what is allowed, and
exit status 2; Ctrl-C during `graft train` exits with status 130 after a final checkpoint."""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn, Optional

from graft.cli.evaluate import add_eval_command
from graft.cli.flags import UsageError
from graft.cli.replay import add_replay_commands
from graft.cli.studies import add_study_commands
from graft.cli.train import add_train_commands
from service import __version__


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad flag is one line (the command, the flag, what is wrong), not the
    usage block; `--help` still shows everything."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The `graft` parser: every command group's commands, Minecraft's where installed."""
    parser = _Parser(
        prog="graft", description="Improve hard-coded policies with distributed off-policy RL."
    )
    parser.add_argument("--version", action="version", version=f"graft {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    add_train_commands(commands)
    add_eval_command(commands)
    add_study_commands(commands)
    add_replay_commands(commands)
    try:
        from minecraft.cli import add_minecraft_commands
    except ImportError:  # the Minecraft simulator is optional at import time
        pass
    else:
        from graft.trained import load_corrections

        add_minecraft_commands(commands, load_corrections)
    return parser


def main(argv: Optional[list[str]] = None) -> None:
    """Runs the command `argv` names; a usage error is one line on stderr, exit status 2."""
    args = build_parser().parse_args(argv if argv is not None else sys.argv[1:])
    handler = getattr(args, "handler", None) or args.func
    try:
        code = handler(args)
    except UsageError as error:
        print(error.message, file=sys.stderr)
        raise
    if isinstance(code, int) and code:
        raise SystemExit(code)
