"""What a `graft` command loads as it starts: the replay server's modules (gRPC, the
tables) only where a replay server runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.service  # a fresh interpreter: this one loaded gRPC long ago
def test_the_cli_loads_the_replay_server_only_where_one_serves() -> None:
    """Building `graft`'s parser (every command, `graft --help`, a refused flag) loads no
    gRPC; `graft replay serve`'s module loads the server in `warm_up`, which the fork
    server runs before it forks `graft train`'s replay servers."""
    script = (
        "import sys; from graft.cli.parser import build_parser; build_parser(); "
        "started = sorted(m for m in ('grpc', 'service.replay.server.serve') if m in sys.modules); "
        "import graft.cli.replay as replay; replay.warm_up(); "
        "print(started, 'service.replay.server.serve' in sys.modules)"
    )
    out = subprocess.run(
        [sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert out.stdout.split() == ["[]", "True"], out.stdout
