"""Weight broadcast: the learner publishes versioned policy weights, actors adopt them.

The learner's `BroadcastPublisher` (a `WeightPublisher`) puts each version into the Ray
object store once, as numpy arrays, and hands one `ObjectRef` to a `WeightBroadcaster`
Ray actor. Every env actor gets a `WeightSubscriber` (a `WeightSource`)::

    learner ──publish(version, [ref])──▶ WeightBroadcaster ◀── up to FANOUT subscribers
                                           ▲   ▲
                              WeightRelay ─┘   └─ WeightRelay   (one per FANOUT subscribers
                                 ▲ ▲ ▲                           on a node, on that node)
                          subscribers on that node

Announcements (a version number and an object ref) travel down this tree by long-poll,
so no broadcaster or relay answers more than FANOUT long-polls (one per subscribing
process, plus its relays) per version, however large the fleet. The weights themselves
never pass through it: each subscribing process fetches the ref from its node's object
store (Ray pulls an object to a node once), zero-copy for numpy arrays.

Subscribers follow their relay from a background thread, one per process and
broadcaster however many subscribers the process holds: it long-polls, fetches each
announced version as it comes (versions announced while a fetch runs are skipped, not
queued) and hands it to every subscriber of the process. The acting thread's `poll()`
only compares two integers unless new weights have arrived.

A follower (a relay's, or a process's) that cannot reach its parent, its node cut off
from the head's network for a while, keeps asking for up to UNREACHABLE_S and goes on
from the newest version once the parent answers again; only a parent that died, or one
unreachable for longer, ends the broadcast for it. A process whose relay died (its node
declared dead while the relay was placed there, or the relay killed) asks the broadcaster
for a new one and goes on; only the broadcaster's own death ends the broadcast.
"""

from __future__ import annotations

import asyncio
import threading
import time
import weakref
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any, Optional

import ray
from ray import ObjectRef
from ray.exceptions import ActorDiedError, ActorUnavailableError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from service.core import as_arrays

if TYPE_CHECKING:
    from service.core import WeightArrays, Weights

FANOUT = 64
"""Long-polls (one per process that subscribes) one broadcaster or relay answers directly;
more on a node get a relay each.
On one node a relay is one more hop and process on the same cores, so groups are large
(README, "Weight broadcast at fleet scale": groups of 16 were slower than none)."""
MAX_WAITERS = 10_000
"""Long-polls one broadcaster or relay holds at once (Ray's default for async actors is
1,000, past which a publish would queue behind long-polls). The fan-out keeps them near
FANOUT plus one per relay."""
POLL_TIMEOUT_S = 30.0
"""How long one long-poll waits for a newer version before it is renewed."""
UNREACHABLE_S = 120.0
"""How long a follower keeps asking a parent it cannot reach (Ray's ActorUnavailableError:
the network between their nodes is down) before it calls the broadcast lost."""
RETRY_S = 1.0
"""The pause between two such asks."""


class _Reachability:
    """How long a follower's parent has not been reachable: `failed()` says whether to
    ask again (or raises the error once UNREACHABLE_S have passed), `answered()` resets."""

    def __init__(self) -> None:
        self._since: Optional[float] = None

    def failed(self, error: ActorUnavailableError) -> None:
        now = time.monotonic()
        self._since = now if self._since is None else self._since
        if now - self._since > UNREACHABLE_S:
            raise error

    def answered(self) -> None:
        self._since = None


BroadcasterHandle = Any
"""A Ray handle to a `WeightBroadcaster` or `WeightRelay`. Ray makes their `.remote`
methods at run time, so mypy cannot check calls through it: only this module makes them,
typing what they return."""

Payload = Mapping[str, Any]
"""Published weights as stored: numpy arrays (`BroadcastPublisher` makes them)."""

_Published = tuple[int, list[ObjectRef[Payload]], bool]
"""What `wait_newer` answers: (version, [weights_ref], stopped)."""


class _Latest:
    """The newest announcement (version, [weights_ref], stopped) and its waiters.

    The ref travels wrapped in a list, so Ray hands it on as a reference: the weights
    are copied into the object store once, never into a reply.
    """

    def __init__(self) -> None:
        self._version = -1
        self._weights_ref: list[ObjectRef[Payload]] = []
        self._stopped = False
        self._changed: Optional[asyncio.Event] = None

    def _event(self) -> asyncio.Event:
        if self._changed is None:  # created inside the actor's event loop
            self._changed = asyncio.Event()
        return self._changed

    def _announce(self, version: int, weights_ref: list[ObjectRef[Payload]], stopped: bool) -> None:
        self._version, self._weights_ref = version, weights_ref
        self._stopped = self._stopped or stopped
        event = self._event()
        self._changed = asyncio.Event()
        event.set()

    async def wait_newer(self, version: int, timeout_s: float = POLL_TIMEOUT_S) -> _Published:
        """Returns (version, [weights_ref], stopped) once a version newer than `version`
        exists or the learner stopped, else the current state after `timeout_s`."""
        await self._started()
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

    async def _started(self) -> None:
        """Hook for a relay to start following its parent inside the event loop."""

    async def version(self) -> int:
        return self._version


@ray.remote(num_cpus=0, max_concurrency=MAX_WAITERS)  # type: ignore[call-overload]  # task-only stubs
class WeightBroadcaster(_Latest):
    """The root of the broadcast: holds the latest (version, weights ref), hands each
    new subscriber the broadcaster or relay it follows."""

    def __init__(self, fanout: int = FANOUT) -> None:
        super().__init__()
        self._fanout = fanout
        self._node_id = ray.get_runtime_context().get_node_id()
        self._attached: dict[str, int] = {}
        self._relays: dict[tuple[str, int], BroadcasterHandle] = {}
        self._group_of: dict[str, tuple[str, int]] = {}
        """Every relay started this run, by actor id: the (node, group) it serves."""

    async def publish(self, version: int, weights_ref: list[ObjectRef[Payload]]) -> None:
        if version <= self._version:
            raise ValueError(f"weight version {version} is not newer than {self._version}")
        self._announce(version, weights_ref, False)

    async def stop(self) -> None:
        """Tells every actor to finish: pending and future polls answer 'stopped'."""
        self._announce(self._version, self._weights_ref, True)

    async def attach(self, node_id: str) -> BroadcasterHandle:
        """Where a process on `node_id` long-polls (its subscribers share one): this
        broadcaster for the first `fanout` on its own node, else that node's relay for
        its group of `fanout`."""
        count = self._attached.get(node_id, 0)
        self._attached[node_id] = count + 1
        group = count // self._fanout
        if node_id == self._node_id and group == 0:
            return ray.get_runtime_context().current_actor
        if (node_id, group) not in self._relays:
            self._start_relay((node_id, group))
        return self._relays[node_id, group]

    async def replace(self, lost: BroadcasterHandle) -> BroadcasterHandle:
        """The relay that now serves the group `lost` (a relay that died) served: one
        started anew, or the one another process of the group asked for first."""
        key = self._group_of[lost._actor_id.hex()]
        if self._relays[key]._actor_id == lost._actor_id:
            self._start_relay(key)
        return self._relays[key]

    def _start_relay(self, key: tuple[str, int]) -> None:
        # Owned by this actor: relays end with the broadcaster. Soft: a node that died
        # meanwhile gets its group's relay placed elsewhere.
        relay = WeightRelay.options(  # type: ignore[attr-defined]
            scheduling_strategy=NodeAffinitySchedulingStrategy(key[0], soft=True)
        ).remote(ray.get_runtime_context().current_actor)
        self._relays[key], self._group_of[relay._actor_id.hex()] = relay, key

    async def reset(self, fanout: int) -> None:
        """Starts over for another run: no version, not stopped, no subscribers, and the
        relays of the last run ended."""
        for relay in self._relays.values():
            ray.kill(relay)
        self._relays.clear()
        self._group_of.clear()
        self._attached.clear()
        self._fanout = fanout
        self._version, self._weights_ref, self._stopped = -1, [], False

    async def relays(self) -> list[BroadcasterHandle]:
        """The relays started so far (for measuring them)."""
        return list(self._relays.values())


@ray.remote(num_cpus=0, max_concurrency=MAX_WAITERS)  # type: ignore[call-overload]  # task-only stubs
class WeightRelay(_Latest):
    """Repeats its parent's announcements to up to `FANOUT` subscribers on its node."""

    def __init__(self, parent: BroadcasterHandle) -> None:
        super().__init__()
        self._parent = parent
        self._follower: Optional[asyncio.Task[None]] = None

    async def _started(self) -> None:
        if self._follower is None:
            self._follower = asyncio.get_running_loop().create_task(self._follow())
        elif self._follower.done() and self._follower.exception() is not None:
            raise RuntimeError("the relay lost its parent") from self._follower.exception()

    async def _follow(self) -> None:
        reach = _Reachability()
        while not self._stopped:
            try:
                reply = await self._parent.wait_newer.remote(self._version)
            except ActorUnavailableError as error:
                reach.failed(error)
                await asyncio.sleep(RETRY_S)
                continue
            reach.answered()
            version, weights_ref, stopped = reply
            if version > self._version or stopped:
                self._announce(version, weights_ref, stopped)


class _ProcessFollower:
    """The one long-poll of a process on a broadcaster, shared by the process's subscribers.

    Its thread attaches once, long-polls, fetches each announced version once and
    delivers it to every live subscriber of the process: N actors in one process cost
    one long-poll, one reply and one fetch per version, not N.
    """

    def __init__(self, broadcaster: BroadcasterHandle, key: str) -> None:
        self._broadcaster, self._key = broadcaster, key
        self._lock = threading.Lock()
        self._subscribers: weakref.WeakSet[WeightSubscriber] = weakref.WeakSet()
        self._latest: tuple[int, Optional[Payload], float] = (-1, None, float("nan"))
        self._stopped = False
        self._error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._follow, name="weights", daemon=True)
        self._thread.start()

    @classmethod
    def join(cls, subscriber: WeightSubscriber) -> None:
        """Adds `subscriber` to its process's follower of its broadcaster (started if none)."""
        # The actor id names the broadcaster across pickled copies of its handle.
        key = subscriber._broadcaster._actor_id.hex()
        with _FOLLOWERS_LOCK:
            follower = _FOLLOWERS.get(key)
            if follower is None:
                follower = _FOLLOWERS[key] = cls(subscriber._broadcaster, key)
            with follower._lock:
                follower._subscribers.add(subscriber)
                version, payload, at = follower._latest
                subscriber._deliver(version, payload, at, follower._stopped, follower._error)

    def _deliver(self) -> None:
        with self._lock:
            version, payload, at = self._latest
            for subscriber in list(self._subscribers):
                subscriber._deliver(version, payload, at, self._stopped, self._error)

    def _follow(self) -> None:
        try:
            node = ray.get_runtime_context().get_node_id()
            source = ray.get(self._broadcaster.attach.remote(node))
            known, reach = -1, _Reachability()
            while not self._stopped:
                try:
                    reply: _Published = ray.get(source.wait_newer.remote(known))
                except ActorUnavailableError as error:
                    reach.failed(error)
                    time.sleep(RETRY_S)
                    continue
                except ActorDiedError:
                    if source._actor_id == self._broadcaster._actor_id:
                        raise
                    source = ray.get(self._broadcaster.replace.remote(source))
                    continue
                reach.answered()
                version, weights_ref, stopped = reply
                if version > known and weights_ref:
                    payload = ray.get(weights_ref[0])
                    self._latest, known = (version, payload, time.time()), version
                self._stopped = stopped
                self._deliver()
        except BaseException as e:  # surfaces on the acting threads, at their next poll
            self._error = e
            self._deliver()
        finally:
            with _FOLLOWERS_LOCK:  # a later subscriber starts afresh (and learns the end)
                if _FOLLOWERS.get(self._key) is self:
                    del _FOLLOWERS[self._key]


_FOLLOWERS: dict[str, _ProcessFollower] = {}
"""This process's followers, by broadcaster actor id."""
_FOLLOWERS_LOCK = threading.Lock()


class WeightSubscriber:
    """An actor's `WeightSource`: `poll()` never blocks; it returns new weights when they arrived.

    A background thread (its process's `_ProcessFollower`) follows the broadcast and
    fetches each announced version; the acting thread's `poll` compares version numbers
    and returns what the thread fetched. It pickles as its broadcaster's handle, so each
    Ray actor it is handed to gets a fresh subscriber; it joins its process's follower
    at the first `poll`, in the process that polls.
    """

    def __init__(self, broadcaster: BroadcasterHandle) -> None:
        self._broadcaster = broadcaster
        self.version = -1
        """Version last returned by `poll` (-1: none yet)."""
        self.stopped = False
        """The learner has finished (set by the background thread)."""
        self.fetched = -1
        """Newest version the background thread holds."""
        self.fetched_at = float("nan")
        """Wall-clock time (`time.time()`) when it arrived."""
        self._payload: Optional[Payload] = None
        self._error: Optional[BaseException] = None
        self._cond = threading.Condition()
        self._joined = False

    def __reduce__(self) -> tuple[type[WeightSubscriber], tuple[BroadcasterHandle]]:
        return WeightSubscriber, (self._broadcaster,)

    def _deliver(
        self,
        version: int,
        payload: Optional[Payload],
        at: float,
        stopped: bool,
        error: Optional[BaseException],
    ) -> None:
        """Called by the follower's thread with its newest state."""
        with self._cond:
            if version > self.fetched and payload is not None:
                self._payload, self.fetched, self.fetched_at = payload, version, at
            self.stopped = self.stopped or stopped
            if error is not None:
                self._error = error
            self._cond.notify_all()

    def poll(self, *, block_s: float = 0.0) -> Optional[WeightArrays]:
        """The newest weights (numpy arrays, as published) if a newer version arrived
        (waiting up to `block_s`), else None.

        Raises:
            RuntimeError: the broadcast was lost (its actor died) before the learner stopped.
        """
        if not self._joined:
            self._joined = True
            _ProcessFollower.join(self)
        if self.fetched <= self.version and self._error is None:  # the per-step cost
            if block_s <= 0:
                return None
            with self._cond:
                self._cond.wait_for(
                    lambda: self.fetched > self.version or self.stopped or self._error is not None,
                    block_s,
                )
        with self._cond:
            if self._error is not None and not self.stopped:
                raise RuntimeError(f"the weight broadcast was lost: {self._error}") from self._error
            if self.fetched <= self.version:
                return None
            self.version, payload, self._payload = self.fetched, self._payload, None
        return None if payload is None else dict(payload)


class BroadcastPublisher:
    """The learner's `WeightPublisher`: starts a `WeightBroadcaster` and publishes to it."""

    def __init__(self, *, fanout: int = FANOUT, kept: Optional[BroadcasterHandle] = None) -> None:
        """``kept``: an idle broadcaster on this node (a finished run's, `release`) to
        publish through, reset for this run; a new one starts instead if it is gone."""
        if kept is not None:
            try:
                ray.get(kept.reset.remote(fanout))
                self._broadcaster: BroadcasterHandle = kept
                return
            except ray.exceptions.RayActorError:  # it died while kept
                pass
        # On the learner's node: a worker node lost with its actors must not take the
        # run's weights along. @ray.remote gives the class `.options` at run time.
        here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=False)
        self._broadcaster = WeightBroadcaster.options(  # type: ignore[attr-defined]
            scheduling_strategy=here
        ).remote(fanout)

    @property
    def broadcaster(self) -> BroadcasterHandle:
        return self._broadcaster

    def publish(self, version: int, weights: Weights) -> None:
        """Makes `weights` version `version`; raises ValueError if that is not newer.

        They are put into the object store once, as numpy arrays: subscribers on a node
        share one copy and read it without deserialising tensors.
        """
        ray.get(self._broadcaster.publish.remote(version, [ray.put(as_arrays(weights))]))

    def subscriber(self) -> WeightSubscriber:
        """A `WeightSource` to hand to an actor."""
        return WeightSubscriber(self._broadcaster)

    def stop(self) -> None:
        """Tells every subscriber to finish: pending and future polls answer 'stopped'."""
        ray.get(self._broadcaster.stop.remote())

    def close(self) -> None:
        """Ends the broadcaster actor (and the relays it owns) now, not when Ray collects
        its last handle: a run that ends must give its CPU share back at once."""
        ray.kill(self._broadcaster)

    def release(self) -> BroadcasterHandle:
        """The broadcaster, alive, for another run to publish through (``kept``)."""
        return self._broadcaster
