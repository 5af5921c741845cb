"""Start a command with a process setting of its own: ``python -m tests.tools.exec_with
[--file-size-limit BYTES] [--default-sigint] -- COMMAND...``.

Tests use it instead of the ``preexec_fn`` of ``subprocess.Popen``, which makes Python
fork rather than spawn, and a test process that has used gRPC (as every process that joined
Ray has) then runs gRPC's fork handlers in the child, which may abort there before the exec.
"""

import argparse
import os
import resource
import signal
import sys


def command(*settings: str) -> list[str]:
    """The argv prefix that runs what follows it with `settings` (this module's flags)."""
    return [sys.executable, "-m", "tests.tools.exec_with", *settings, "--"]


def main() -> None:
    parser = argparse.ArgumentParser(prog="exec_with")
    parser.add_argument("--file-size-limit", type=int, help="RLIMIT_FSIZE in bytes")
    parser.add_argument(
        "--default-sigint", action="store_true", help="Ctrl-C's default, even if ignored here"
    )
    parser.add_argument("command", nargs="+")
    args = parser.parse_args()
    if args.file_size_limit is not None:
        limit = args.file_size_limit
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    if args.default_sigint:  # an ignored signal stays ignored across exec; a default one resets
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    os.execvp(args.command[0], args.command)


if __name__ == "__main__":
    main()
