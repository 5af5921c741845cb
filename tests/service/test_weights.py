"""The weight broadcast on a real local Ray: the learner's publisher, actors' subscribers."""

from __future__ import annotations

import pickle
import time

import numpy as np
import pytest
import ray
import torch

from service.weights import BroadcastPublisher, WeightRelay, WeightSubscriber


@ray.remote(num_cpus=0)
class Follower:
    """An actor following the broadcast in a process of its own (its own long-poll)."""

    def follow(
        self, subscriber: WeightSubscriber, last: int
    ) -> tuple[list[int], dict[str, np.ndarray]]:
        versions, weights = [], None
        while subscriber.version < last:
            if (new := subscriber.poll(block_s=1.0)) is not None:
                versions.append(subscriber.version)
                weights = new
        return versions, weights


def adopt(subscriber: WeightSubscriber) -> dict[str, np.ndarray]:
    """What an actor does before acting: poll until weights arrive."""
    weights = None
    while weights is None:
        assert not subscriber.stopped
        weights = subscriber.poll(block_s=1.0)
    return weights


def test_a_subscriber_handed_to_a_ray_task_receives_what_the_learner_publishes(ray_local):
    # Defined here so that Ray ships it by value: workers cannot import this test module.
    @ray.remote
    def first_weights(subscriber: WeightSubscriber) -> tuple[int, dict[str, np.ndarray]]:
        weights = None
        while weights is None:
            weights = subscriber.poll(block_s=1.0)
        return subscriber.version, weights

    publisher = BroadcastPublisher()
    waiting = [first_weights.remote(publisher.subscriber()) for _ in range(2)]
    publisher.publish(0, {"w": torch.ones(2)})
    for version, weights in ray.get(waiting):
        assert version == 0
        assert np.array_equal(weights["w"], np.ones(2))
    publisher.stop()


def test_a_subscriber_pickles_as_a_fresh_subscriber_of_the_same_broadcaster(ray_local):
    publisher = BroadcastPublisher()
    publisher.publish(3, {"w": torch.zeros(1)})
    used = publisher.subscriber()
    adopt(used)
    assert used.version == 3
    copy = pickle.loads(pickle.dumps(used))
    assert copy.version == -1  # it has adopted nothing yet
    adopt(copy)
    assert copy.version == 3
    publisher.stop()


def test_stop_reaches_every_subscriber_and_old_versions_are_refused(ray_local):
    publisher = BroadcastPublisher()
    publisher.publish(1, {"w": torch.zeros(1)})
    with pytest.raises(ValueError, match="not newer"):
        publisher.publish(1, {"w": torch.zeros(1)})
    subscriber = publisher.subscriber()
    adopt(subscriber)
    publisher.stop()
    while not subscriber.stopped:
        assert subscriber.poll(block_s=1.0) is None  # nothing newer than version 1


def test_subscribers_past_the_fanout_follow_relays_and_all_get_the_newest_version(ray_local):
    publisher = BroadcastPublisher(fanout=2)
    followers = [Follower.remote() for _ in range(5)]  # an actor each: five long-polls
    runs = [f.follow.remote(publisher.subscriber(), 2) for f in followers]
    for version in range(3):
        publisher.publish(version, {"w": torch.full((3,), float(version))})
    for versions, weights in ray.get(runs, timeout=60):
        assert versions[-1] == 2 and versions == sorted(set(versions))
        assert np.array_equal(weights["w"], np.full(3, 2.0))
    # One node: the broadcaster answers the first 2 subscribers, a relay each further 2.
    assert len(ray.get(publisher.broadcaster.relays.remote())) == 2
    publisher.stop()
    for f in followers:
        ray.kill(f)


def test_a_process_whose_relay_died_follows_a_new_one_and_gets_the_next_version(ray_local):
    # A relay dies when Ray declares its node dead (placed on a node cut off from the
    # cluster's network); its subscribers must not: the broadcaster starts another.
    publisher = BroadcastPublisher(fanout=1)
    adopt_first = publisher.subscriber()  # this process: the broadcaster's one long-poll
    publisher.publish(0, {"w": torch.zeros(1)})
    adopt(adopt_first)
    follower = Follower.remote()  # another process on the node: a relay's
    run = follower.follow.remote(publisher.subscriber(), 1)
    while not (relays := ray.get(publisher.broadcaster.relays.remote())):
        time.sleep(0.1)  # until the follower's process has attached
    [relay] = relays
    while ray.get(relay.version.remote()) < 0:
        time.sleep(0.1)
    ray.kill(relay)
    publisher.publish(1, {"w": torch.ones(1)})
    versions, weights = ray.get(run, timeout=60)
    assert versions[-1] == 1 and np.array_equal(weights["w"], np.ones(1))
    [new] = ray.get(publisher.broadcaster.relays.remote())
    assert new._actor_id != relay._actor_id
    publisher.stop()
    ray.kill(follower)


def test_subscribers_in_one_process_share_one_long_poll(ray_local):
    # Fan-out 1: were each of the three its own long-poll, two would need relays.
    publisher = BroadcastPublisher(fanout=1)
    subscribers = [publisher.subscriber() for _ in range(3)]
    for version in range(2):
        publisher.publish(version, {"w": torch.full((2,), float(version))})
        for subscriber in subscribers:
            while subscriber.version < version:
                adopt(subscriber)
    assert {s.version for s in subscribers} == {1}
    assert ray.get(publisher.broadcaster.relays.remote()) == []
    # A subscriber that joins later gets the newest version at once, and the end.
    late = publisher.subscriber()
    assert np.array_equal(adopt(late)["w"], np.ones(2)) and late.version == 1
    publisher.stop()
    for subscriber in [*subscribers, late]:
        while not subscriber.stopped:
            assert subscriber.poll(block_s=1.0) is None
    publisher.close()


def test_an_actor_whose_broadcast_died_fails_instead_of_acting_on_stale_weights(ray_local):
    publisher = BroadcastPublisher()
    publisher.publish(0, {"w": torch.zeros(1)})
    subscriber = publisher.subscriber()
    adopt(subscriber)
    ray.kill(publisher.broadcaster)
    with pytest.raises(RuntimeError, match="weight broadcast was lost"):
        for _ in range(30):
            subscriber.poll(block_s=1.0)


def test_a_relay_cut_off_from_its_parent_for_a_while_goes_on_when_it_answers(ray_local):
    # A parent that is unreachable for its first three asks (a node cut off from the
    # head's network), then answers: the relay and its subscriber get the version.
    @ray.remote
    class CutOff:
        def __init__(self, parent):
            self.parent, self.failures = parent, 3

        async def wait_newer(self, version, timeout_s=30.0):
            if self.failures:
                self.failures -= 1
                raise ray.exceptions.ActorUnavailableError("the network is down", None)
            return await self.parent.wait_newer.remote(version, timeout_s)

    publisher = BroadcastPublisher()
    publisher.publish(0, {"w": torch.ones(1)})
    relay = WeightRelay.remote(CutOff.remote(publisher.broadcaster))
    version, weights_ref, stopped = ray.get(relay.wait_newer.remote(-1, 1.0))
    while version < 0:  # each ask the cut-off parent refuses costs RETRY_S
        version, weights_ref, stopped = ray.get(relay.wait_newer.remote(-1, 1.0))
    assert (version, stopped) == (0, False)
    assert np.array_equal(ray.get(weights_ref[0])["w"], np.ones(1))
    publisher.close()
