"""Starting and stopping a replay server as a separate OS process."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Optional

from service import forkserver

EXIT_FOLDER_UNUSABLE = 3
"""`graft replay serve`'s exit status when its --checkpoint-dir cannot be restored for its
tables (the folder is left as it was)."""


class FolderRefused(RuntimeError):
    """The server refused its checkpoint folder at start-up; the message is its reason."""


class ReplayProcess:
    """A `graft replay serve` process (a fork of the replay server's fork server,
    `service.forkserver`); `address` is known once it listens.

    `token` (None: the server takes none, whatever this process's GRAFT_TOKEN) reaches
    the child in its environment, never on its command line.
    """

    def __init__(
        self,
        tables: list[dict[str, Any]],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        token: Optional[str] = None,
        log_path: Optional[Path] = None,
        startup_timeout_s: float = 60.0,
        extra_args: Sequence[str] = (),
    ) -> None:
        self._dir = tempfile.TemporaryDirectory(prefix="graft-replay-")
        config = Path(self._dir.name) / "tables.json"
        config.write_text(json.dumps({"tables": tables}))
        ready = Path(self._dir.name) / "ready.json"
        command = [
            "serve",
            "--config",
            str(config),
            "--host",
            host,
            "--port",
            str(port),
            "--ready-file",
            str(ready),
            "--exit-with-parent",
            str(os.getpid()),
            *extra_args,
        ]
        # The token goes by environment: a command line is readable by every local user.
        env = {k: v for k, v in os.environ.items() if k != "GRAFT_TOKEN"}
        # It does no linear algebra: one OpenBLAS thread, not a spinning pool per core
        # (0.12 s less CPU a start on 2 cores, bench/server_starts.py).
        env.setdefault("OPENBLAS_NUM_THREADS", "1")
        if token:
            env["GRAFT_TOKEN"] = token
        self.process = forkserver.start(
            "graft.cli.replay", command, env=env, output=str(log_path) if log_path else None
        )
        try:
            self._wait_until_ready(ready, startup_timeout_s, log_path)
        except BaseException:  # failed, timed out or Ctrl-C: no server outlives its start
            self.stop()
            raise
        self.address: str = json.loads(ready.read_text())["address"]

    def _wait_until_ready(self, ready: Path, timeout_s: float, log_path: Optional[Path]) -> None:
        deadline = time.monotonic() + timeout_s
        while not ready.exists():
            if self.process.poll() is not None:
                if self.process.returncode == EXIT_FOLDER_UNUSABLE:
                    raise FolderRefused(_last_line(log_path) or "its checkpoint folder is unusable")
                raise RuntimeError(
                    f"replay server exited with code {self.process.returncode} during start-up"
                    + (f"; see {log_path}" if log_path else "")
                )
            if time.monotonic() > deadline:
                raise TimeoutError(f"replay server did not start within {timeout_s}s")
            time.sleep(0.05)

    def stop(self, timeout_s: float = 15.0) -> None:
        """SIGTERM (graceful: final checkpoint, drain), then SIGKILL if it hangs."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._dir.cleanup()

    def kill(self) -> None:
        """SIGKILL: no goodbye, no final checkpoint (for crash tests)."""
        self.process.kill()
        self.process.wait()

    def __enter__(self) -> ReplayProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _last_line(log_path: Optional[Path]) -> Optional[str]:
    """The server's last line of output, without its `graft replay serve: ` prefix."""
    if log_path is None:
        return None
    lines = log_path.read_text(errors="replace").strip().splitlines()
    return lines[-1].removeprefix("graft replay serve: ") if lines else None
