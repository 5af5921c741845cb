"""Exactly-once bookkeeping: high-water marks, their bound, and in-flight claims."""

from __future__ import annotations

import pytest

from service.replay.server.writers import Claim, Writers


def test_a_claim_is_held_by_one_call_until_released():
    writers, first, second = Writers(), object(), object()
    assert writers.claim("w", 1, first) is Claim.CLAIMED
    assert writers.claim("w", 1, first) is Claim.CLAIMED  # the same call again
    assert writers.claim("w", 1, second) is Claim.BUSY
    writers.release(first, [("w", 1)])
    assert writers.claim("w", 1, second) is Claim.CLAIMED


def test_a_stored_batch_is_a_resend_for_every_call():
    writers, call = Writers(), object()
    writers.claim("w", 2, call)
    writers.ack("w", 2)
    writers.release(call, [("w", 2)])
    assert writers.claim("w", 1, object()) is Claim.STORED
    assert writers.claim("w", 2, object()) is Claim.STORED
    assert writers.claim("w", 3, object()) is Claim.CLAIMED


def test_releasing_leaves_other_calls_claims_alone():
    writers, first, second = Writers(), object(), object()
    writers.claim("w", 1, first)
    writers.release(second, [("w", 1)])
    assert writers.claim("w", 1, second) is Claim.BUSY


def test_the_least_recently_stored_writer_is_forgotten_first():
    writers = Writers(max_writers=2)
    writers.ack("a", 1)
    writers.ack("b", 1)
    writers.ack("a", 2)  # a is now the most recent
    writers.ack("c", 1)
    assert (writers.acked("a"), writers.acked("b"), writers.acked("c")) == (2, 0, 1)
    assert list(writers.snapshot()) == ["a", "c"]


def test_a_restore_keeps_the_most_recent_writers_within_the_bound():
    writers = Writers(max_writers=2)
    writers.restore({"old": 5, "mid": 6, "new": 7})  # oldest first, as a snapshot is
    assert writers.snapshot() == {"mid": 6, "new": 7}


def test_the_bound_must_be_positive():
    with pytest.raises(ValueError, match="max_writers must be >= 1"):
        Writers(max_writers=0)
