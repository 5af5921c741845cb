"""Benchmark: what starting a replay server and a world server costs, this tree against an
earlier commit's (default: the parent of the change that made them cheaper).

The launcher starts a replay server per run and shard, and a run of Minecraft clients a
world server per client, so their start-up is paid again and again: by a sweep, by a
supervisor's restarts, and by the tests (~190 replay servers a `make test`). Each start is
a fresh interpreter that starts the server the way a run does (`ReplayProcess`,
`ServerPool`), waits until it answers and stops it. Both trees are byte-compiled copies;
the two alternate, `--starts` each per round, so another job on the machine moves both
alike. CPU is the children's (user + system), server processes included. The ratio is
the figure.

    python bench/server_starts.py [--base REV] [--starts 10] [--rounds 2]
"""

from __future__ import annotations

import argparse
import compileall
import io
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.compiled_starts import (  # noqa: E402
    PACKAGES,
    ROOT,
    SERVE,
    compare_starts,
    copy_tree,
    parse_rounds,
)

BASE = "58fd2ad"
"""The last commit before replay and world servers ran with one OpenBLAS thread and
loaded Prometheus only for a metrics port."""
WORLD = (
    "from minecraft.sim.pool import ServerPool; pool = ServerPool(1, 0); pool.start(); pool.stop()"
)
KINDS = {"replay server": SERVE, "world server": WORLD}


def export(rev: str, to: Path) -> Path:
    """graft's packages as of commit `rev`."""
    archive = subprocess.run(
        ["git", "archive", rev, *PACKAGES], cwd=ROOT, check=True, capture_output=True
    ).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(to, filter="data")
    return to


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--base", default=BASE, help=f"the commit to compare with ({BASE})")
    args = parse_rounds(parser)
    with tempfile.TemporaryDirectory() as tmp:
        trees = {
            args.base: export(args.base, Path(tmp) / "base"),
            "this tree": copy_tree(Path(tmp) / "now"),
        }
        for tree in trees.values():
            for name in PACKAGES:
                compileall.compile_dir(tree / name, quiet=1, workers=0)
        compare_starts(trees, KINDS, starts=args.starts, rounds=args.rounds)


if __name__ == "__main__":
    main()
