"""A module for the fork-server tests: `main(argv)` prints what it was started with, then
ends as `argv` asks (return N, exit N, exit-message TEXT, raise TEXT, sleep SECONDS)."""

from __future__ import annotations

import json
import os
import sys
import time


def main(argv: list[str]) -> int:
    seen = {"argv": argv, "sys.argv": sys.argv[1:], "x": os.environ.get("FORKEE_X")}
    print(json.dumps({**seen, "cwd": os.getcwd()}), flush=True)
    how, what = argv[:2]
    if how == "exit":
        raise SystemExit(int(what))
    if how == "exit-message":
        raise SystemExit(what)
    if how == "raise":
        raise RuntimeError(what)
    if how == "sleep":
        time.sleep(float(what))
        return 0
    return int(what)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
