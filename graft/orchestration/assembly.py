"""The one place a run's parts are put together and taken apart: `graft train`, `graft
experiment` (through `driver.train_here`) and every `graft tune` point (`tuning.sweep`) build
their Ray instance, replay servers, weight broadcaster, step budget, env actors and
evaluator here, in that order, and this module tears them down in reverse order, whatever
ends the run::

    with RunParts(address) as parts:
        parts.connect()                      # Ray; shut down at the end if started here
        replay = parts.replay(open_run_replay)
        publisher = parts.broadcaster()
        evaluator = parts.evaluator(make_evaluator, key)
        actors = parts.actors(fleet, key)
        ...                                  # the learner loop
        parts.keep = True                    # ended well: kept parts are handed on

A run that ended well (`keep`) on a Ray instance that stays hands its Ray helpers on to
the next run (kept.py); any other end stops or kills them.
"""

from __future__ import annotations

import contextlib
import secrets
from collections.abc import Callable
from contextlib import AbstractContextManager
from types import TracebackType
from typing import Any, Optional, TypeVar

import ray

from graft.orchestration.kept import BROADCASTER, BUDGET, ENV_ACTORS, EVALUATOR, KEPT
from graft.orchestration.ray_session import connect_ray
from graft.orchestration.supervision import ActorFleet
from service.weights import BroadcastPublisher

T = TypeVar("T")


def replay_endpoint(address: str) -> tuple[str, Optional[str]]:
    """Where a run's replay server listens, and its token: loopback and none on a local Ray
    instance; beyond one machine the network, and then it needs a token."""
    if address == "local":
        return "127.0.0.1", None
    return "0.0.0.0", secrets.token_urlsafe(24)


class RunParts:
    """A run's parts, each registered as it is built; leaving the ``with`` block ends them
    in reverse order (an `contextlib.ExitStack`)."""

    def __init__(self, address: str) -> None:
        self.address = address
        self.host, self.token = replay_endpoint(address)
        self.keep = False
        """Set once the run ended well: its Ray helpers are then handed on to the next run
        (where Ray stays up), not ended."""
        self.keep_actors = True
        """Whether the env actors may be handed on too (not when they may still act)."""
        self._started_ray = False
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> RunParts:
        self._stack.__enter__()
        return self

    def __exit__(
        self,
        kind: Optional[type[BaseException]],
        error: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> Optional[bool]:
        return self._stack.__exit__(kind, error, traceback)

    @property
    def handing_on(self) -> bool:
        """Whether kept parts go to the next run: the run ended well and Ray stays up."""
        return self.keep and not self._started_ray

    @property
    def node(self) -> str:
        """This process's Ray node (the learner's)."""
        return str(ray.get_runtime_context().get_node_id())

    def on_exit(self, callback: Callable[[], Any]) -> None:
        """Calls `callback` when the run's parts are torn down (after those built later)."""
        self._stack.callback(callback)

    def enter(self, context: AbstractContextManager[T]) -> T:
        """Enters `context` now and exits it at teardown."""
        return self._stack.enter_context(context)

    def connect(self) -> None:
        """Joins Ray at the address (starting a local instance for 'local'); an instance
        started here is shut down last."""
        self._started_ray = connect_ray(self.address)
        if self._started_ray:
            self.on_exit(ray.shutdown)

    def replay(self, start: Callable[[], T], stop: Callable[[T], Any]) -> T:
        """The run's replay server(s), from `start`; stopped by `stop` at teardown."""
        replay = start()
        self.on_exit(lambda: stop(replay))
        return replay

    def broadcaster(self) -> BroadcastPublisher:
        """The weight broadcaster (a kept one where there is one on this node)."""
        node = self.node
        publisher = BroadcastPublisher(kept=KEPT.take(BROADCASTER, node))
        self._hand_on(BROADCASTER, node, lambda: [publisher.release()], publisher.close)
        return publisher

    def evaluator(self, start: Callable[[Any], T], key: str) -> T:
        """The evaluator `start` makes from a kept actor (or None) of `key`'s options."""
        evaluator: Any = start(KEPT.take(EVALUATOR, key))
        self._hand_on(EVALUATOR, key, lambda: [evaluator.release()], evaluator.close)
        return evaluator  # type: ignore[no-any-return]

    def actors(self, fleet: ActorFleet, key: str, budget: Optional[Any] = None) -> ActorFleet:
        """The env actors (and the step budget they share): handed on only when
        `keep_actors` still holds at teardown, else killed."""

        def hand_on() -> None:
            if self.handing_on and self.keep_actors:
                KEPT.keep(ENV_ACTORS, key, *fleet.release())
                if budget is not None:
                    KEPT.keep(BUDGET, self.node, budget)
            else:
                fleet.kill()

        self.on_exit(hand_on)
        return fleet

    def _hand_on(
        self, role: str, key: str, release: Callable[[], list[Any]], end: Callable[[], Any]
    ) -> None:
        def hand_on() -> None:
            if self.handing_on:
                KEPT.keep(role, key, *release())
            else:
                end()

        self.on_exit(hand_on)
