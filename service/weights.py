"""Weight broadcast: the learner publishes versioned policy weights, actors adopt them.

Each actor keeps exactly one outstanding long-poll (`wait_newer`) that resolves when
a newer version is published, so there is no polling storm however many actors run.
"""

from __future__ import annotations

import asyncio
from typing import Any, Optional

import ray


@ray.remote(num_cpus=0)
class WeightBroadcaster:
    """Holds the latest (version, weights) and wakes waiting actors on publish.

    Weights travel as an object-store reference wrapped in a list, so publishing
    copies them once into the object store, not once per actor.
    """

    def __init__(self) -> None:
        self._version = -1
        self._weights_ref: list[Any] = []
        self._changed: Optional[asyncio.Event] = None
        self._stopped = False

    def _event(self) -> asyncio.Event:
        if self._changed is None:  # created inside the actor's event loop
            self._changed = asyncio.Event()
        return self._changed

    async def publish(self, version: int, weights_ref: list[Any]) -> None:
        if version <= self._version:
            raise ValueError(f"weight version {version} is not newer than {self._version}")
        self._version, self._weights_ref = version, weights_ref
        event = self._event()
        self._changed = asyncio.Event()
        event.set()

    async def stop(self) -> None:
        """Tells every actor to finish: pending and future polls answer 'stopped'."""
        self._stopped = True
        self._event().set()

    async def wait_newer(
        self, version: int, timeout_s: float = 30.0
    ) -> tuple[int, list[Any], bool]:
        """Returns (version, [weights_ref], stopped) once a version newer than `version` exists."""
        deadline = asyncio.get_running_loop().time() + timeout_s
        while self._version <= version and not self._stopped:
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                break
            try:
                await asyncio.wait_for(self._event().wait(), remaining)
            except TimeoutError:
                break
        return self._version, self._weights_ref, self._stopped

    async def version(self) -> int:
        return self._version


class WeightSubscriber:
    """Actor-side handle: `poll()` never blocks; it returns new weights when they arrived."""

    def __init__(self, broadcaster: Any) -> None:
        self._broadcaster = broadcaster
        self.version = -1
        self.stopped = False
        self._pending = broadcaster.wait_newer.remote(self.version)

    def poll(self, *, block_s: float = 0.0) -> Optional[Any]:
        """Returns the newest weights if a newer version arrived, else None."""
        ready, _ = ray.wait([self._pending], timeout=block_s)
        if not ready:
            return None
        version, weights_ref, self.stopped = ray.get(self._pending)
        weights = None
        if version > self.version and weights_ref:
            weights = ray.get(weights_ref[0])
            self.version = version
        if not self.stopped:
            self._pending = self._broadcaster.wait_newer.remote(self.version)
        return weights
