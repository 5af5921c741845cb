"""The weight broadcast on a real local Ray: the learner's publisher, actors' subscribers."""

from __future__ import annotations

import pickle

import pytest
import ray
import torch

from service.weights import BroadcastPublisher, WeightSubscriber


def adopt(subscriber: WeightSubscriber) -> dict[str, torch.Tensor]:
    """What an actor does before acting: poll until weights arrive."""
    weights = None
    while weights is None:
        assert not subscriber.stopped
        weights = subscriber.poll(block_s=1.0)
    return weights


def test_a_subscriber_handed_to_a_ray_task_receives_what_the_learner_publishes(ray_local):
    # Defined here so that Ray ships it by value: workers cannot import this test module.
    @ray.remote
    def first_weights(subscriber: WeightSubscriber) -> tuple[int, dict[str, torch.Tensor]]:
        weights = None
        while weights is None:
            weights = subscriber.poll(block_s=1.0)
        return subscriber.version, weights

    publisher = BroadcastPublisher()
    waiting = [first_weights.remote(publisher.subscriber()) for _ in range(2)]
    publisher.publish(0, {"w": torch.ones(2)})
    for version, weights in ray.get(waiting):
        assert version == 0
        assert torch.equal(weights["w"], torch.ones(2))
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
