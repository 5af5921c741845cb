"""The run's replay server, restarted from its checkpoint folder on the same port when it
dies, so clients reconnect to the address they know."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional

from graft.replay_host.process import ReplayProcess


class TooManyRestarts(RuntimeError):
    """A role died more often than its ``max_restarts`` allows."""


class SupervisedReplay:
    """The run's replay server; `check()` restarts it on the same port and checkpoint
    folder when it has died, so clients reconnect to the address they know."""

    def __init__(
        self,
        tables: list[dict[str, Any]],
        *,
        host: str,
        port: int,
        token: Optional[str],
        checkpoint_dir: Path,
        checkpoint_every_s: float,
        log_path: Path,
        max_restarts: int,
    ) -> None:
        self._tables, self._host, self._token = tables, host, token
        self._log_path, self.max_restarts = log_path, max_restarts
        self._args = [
            "--checkpoint-dir",
            str(checkpoint_dir),
            "--checkpoint-every-s",
            str(checkpoint_every_s),
        ]
        self.restarts = 0
        self.process = self._start(port)
        self.address = self.process.address
        self.port = int(self.address.rsplit(":", 1)[1])

    def _start(self, port: int) -> ReplayProcess:
        return ReplayProcess(
            self._tables,
            host=self._host,
            port=port,
            token=self._token,
            log_path=self._log_path,
            extra_args=self._args,
        )

    def check(self) -> Optional[str]:
        """Restarts a dead server; returns the line saying so (None if it is alive).

        Raises:
            TooManyRestarts: it died more than `max_restarts` times.
        """
        code = self.process.process.poll()
        if code is None:
            return None
        self.process.stop()  # reaps it and cleans up its start-up files
        if self.restarts >= self.max_restarts:
            raise TooManyRestarts(
                f"the replay server died (exit code {code}) after {self.restarts} restarts "
                f"(replay.max_restarts={self.max_restarts}); see {self._log_path}"
            )
        self.restarts += 1
        self.process = self._start(self.port)
        return (
            f"replay server died (exit code {code}); restarted from its checkpoint folder "
            f"on port {self.port} (restart {self.restarts})"
        )

    def stop(self) -> None:
        self.process.stop()
