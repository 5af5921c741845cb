"""Weight broadcast: the learner publishes versioned policy weights, actors adopt them.

The learner's `BroadcastPublisher` (a `WeightPublisher`) starts a `WeightBroadcaster`
Ray actor; every env actor gets a `WeightSubscriber` (a `WeightSource`) from it. Each
subscriber keeps exactly one outstanding long-poll (`wait_newer`) that resolves when a
newer version is published, so there is no polling storm however many actors run.
"""

from __future__ import annotations

import asyncio
from typing import Any, Optional

import ray
from ray import ObjectRef

from service.core import Weights

BroadcasterHandle = Any
"""A Ray handle to a `WeightBroadcaster`. Ray makes its `.remote` methods at run time, so
mypy cannot check calls through it: only this module makes them, typing what they return."""

_Published = tuple[int, list[ObjectRef[Weights]], bool]
"""What `WeightBroadcaster.wait_newer` answers: (version, [weights_ref], stopped)."""


@ray.remote(num_cpus=0)
class WeightBroadcaster:
    """Holds the latest (version, weights) and wakes waiting actors on publish.

    Weights travel as an object-store reference wrapped in a list, so publishing
    copies them once into the object store, not once per actor.
    """

    def __init__(self) -> None:
        self._version = -1
        self._weights_ref: list[ObjectRef[Weights]] = []
        self._changed: Optional[asyncio.Event] = None
        self._stopped = False

    def _event(self) -> asyncio.Event:
        if self._changed is None:  # created inside the actor's event loop
            self._changed = asyncio.Event()
        return self._changed

    async def publish(self, version: int, weights_ref: list[ObjectRef[Weights]]) -> None:
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

    async def wait_newer(self, version: int, timeout_s: float = 30.0) -> _Published:
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
    """An actor's `WeightSource`: `poll()` never blocks; it returns new weights when they arrived.

    It pickles as its broadcaster's handle, so each Ray actor it is handed to gets a fresh
    subscriber; its long-poll starts at the first `poll`, in the process that polls.
    """

    def __init__(self, broadcaster: BroadcasterHandle) -> None:
        self._broadcaster = broadcaster
        self.version = -1
        self.stopped = False
        self._pending: Optional[ObjectRef[_Published]] = None

    def __reduce__(self) -> tuple[type[WeightSubscriber], tuple[BroadcasterHandle]]:
        return WeightSubscriber, (self._broadcaster,)

    def _wait_newer(self) -> ObjectRef[_Published]:
        ref: ObjectRef[_Published] = self._broadcaster.wait_newer.remote(self.version)
        return ref

    def poll(self, *, block_s: float = 0.0) -> Optional[Weights]:
        """Returns the newest weights if a newer version arrived, else None."""
        if self._pending is None:
            self._pending = self._wait_newer()
        ready, _ = ray.wait([self._pending], timeout=block_s)
        if not ready:
            return None
        version, weights_ref, self.stopped = ray.get(self._pending)
        weights = None
        if version > self.version and weights_ref:
            weights = ray.get(weights_ref[0])
            self.version = version
        if not self.stopped:
            self._pending = self._wait_newer()
        return weights


class BroadcastPublisher:
    """The learner's `WeightPublisher`: starts a `WeightBroadcaster` and publishes to it."""

    def __init__(self) -> None:
        # @ray.remote gives the class `.remote` at run time; mypy sees the plain class.
        self._broadcaster: BroadcasterHandle = WeightBroadcaster.remote()  # type: ignore[attr-defined]

    def publish(self, version: int, weights: Weights) -> None:
        """Makes `weights` version `version`; raises ValueError if that is not newer."""
        ray.get(self._broadcaster.publish.remote(version, [ray.put(weights)]))

    def subscriber(self) -> WeightSubscriber:
        """A `WeightSource` to hand to an actor."""
        return WeightSubscriber(self._broadcaster)

    def stop(self) -> None:
        """Tells every subscriber to finish: pending and future polls answer 'stopped'."""
        ray.get(self._broadcaster.stop.remote())
