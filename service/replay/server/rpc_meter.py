"""What the servicer reports of each call: refusals, payload bytes and handling time.

A server with a metrics port reports them to Prometheus (`prom.ReplayMetrics`); one
without reports them to nothing, and so never loads prometheus_client and its HTTP
server (bench/server_starts.py)."""

from __future__ import annotations

from typing import Protocol


class RpcMeter(Protocol):
    def refused(self, code: str) -> None:
        """A call refused with the gRPC status named `code`."""

    def received(self, nbytes: int) -> None:
        """Payload bytes of an inserted batch."""

    def sent(self, nbytes: int) -> None:
        """Payload bytes of a sampled batch."""

    def handled(self, method: str, seconds: float) -> None:
        """One call of `method` (Insert, Sample) handled in `seconds`."""


class NoMeter:
    """The meter of a server no one scrapes: it keeps nothing."""

    def refused(self, code: str) -> None:
        pass

    def received(self, nbytes: int) -> None:
        pass

    def sent(self, nbytes: int) -> None:
        pass

    def handled(self, method: str, seconds: float) -> None:
        pass
