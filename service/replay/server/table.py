"""A replay table: preallocated item records with a sampler, a remover and a rate limiter.

Items are keyed by insertion number. Actors write trajectories; a sample of k-step
windows follows each episode's links (service/replay/server/episodes.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from service.replay.codec import Batch, stack_batches
from service.replay.server.episodes import EpisodeLinks
from service.replay.server.prepared_insert import PreparedInsert, prepare_insert
from service.replay.server.rate_limiters import MinSize, RateLimiter
from service.replay.server.records import record_layout
from service.replay.server.samplers import Prioritized, Sampler, Uniform
from service.replay.server.signature import Signature
from service.replay.server.slots import FreeListSlots, RingSlots
from service.replay.server.table_checks import check_configuration
from service.replay.server.table_memory import sampled_bytes


class RateLimitTimeout(TimeoutError):
    """The rate limiter (or the wait for a complete window) outlasted the call's timeout."""


class LockBusy(Exception):
    """A non-blocking attempt found a lock held; retry where blocking is fine."""


@dataclass
class TableStats:
    """Counters a table reports through Info and metrics."""

    inserts: int = 0
    samples: int = 0
    insert_blocked_s: float = 0.0
    sample_blocked_s: float = 0.0


class Table:
    """One named table; thread-safe (inserts and samples come from many worker threads)."""

    def __init__(
        self,
        name: str,
        *,
        max_size: int,
        signature: Signature,
        sampler: Optional[Sampler] = None,
        remover: str = "fifo",
        rate_limiter: Optional[RateLimiter] = None,
        max_times_sampled: int = 0,
        max_sequence_length: int = 1,
        seed: Optional[int] = None,
    ) -> None:
        self.name = name
        self.max_size = max_size
        self.signature = signature
        self.sampler = sampler or Uniform()
        self.remover = remover
        self.rate_limiter = rate_limiter or MinSize(1)
        self.max_times_sampled = max_times_sampled
        self.max_sequence_length = max_sequence_length
        check_configuration(
            f"table '{name}'",
            max_size=max_size,
            sampler=self.sampler,
            remover=remover,
            rate_limiter=self.rate_limiter,
            max_times_sampled=max_times_sampled,
            max_sequence_length=max_sequence_length,
        )
        self.stats = TableStats()
        if remover == "fifo" and max_times_sampled == 0:
            self.slots: RingSlots | FreeListSlots = RingSlots(max_size)
        else:
            self.slots = FreeListSlots(max_size, evict_newest=remover == "lifo")
        if isinstance(self.sampler, Prioritized):
            self.sampler.bind(max_size)
        # Item-major storage: an item's columns lie side by side in one record, so a sample
        # reads each drawn item from one place in memory, not one place per column (with
        # random rows, the memory accesses are what a sample costs). Columns are views.
        self._fields, record_bytes = record_layout(signature)
        self._records = np.zeros((max_size, record_bytes), dtype=np.uint8)
        self._columns = {c: field.of(self._records) for c, field in self._fields.items()}
        self._times_sampled = np.zeros(max_size if max_times_sampled else 0, dtype=np.int32)
        self._links = EpisodeLinks(self.slots, max_size, enabled=max_sequence_length > 1)
        self._ends = [c for c in ("terminated", "truncated") if c in signature.columns]
        self._rng = np.random.default_rng(seed)
        self._cond = threading.Condition()
        self._watchers: list[Callable[[], None]] = []
        self._sample_log: Optional[Callable[[str, int], None]] = None
        self._item_bytes = signature.item_bytes  # asked on every sample request
        # Batches drawn together equal batches drawn in a row: each draw is independent of
        # the last (not fifo/lifo), and sampling removes no item.
        self._draws_independent = (
            isinstance(self.sampler, (Uniform, Prioritized)) and not max_times_sampled
        )

    @property
    def size(self) -> int:
        return self.slots.size

    @property
    def bytes_in_memory(self) -> int:
        arrays: list[np.ndarray] = [self._records, self._times_sampled, self._links.next_key]
        if isinstance(self.slots, FreeListSlots):
            arrays.append(self.slots.keys)
        return sum(a.nbytes for a in arrays)

    @property
    def bytes_used(self) -> int:
        """Bytes the stored items fill: their share of the arrays sized by max_size."""
        return self.bytes_in_memory * self.size // self.max_size

    def describe(self) -> dict[str, str]:
        return {
            "sampler": self.sampler.describe(),
            "remover": self.remover,
            "rate_limiter": self.rate_limiter.describe(),
        }

    def watch(self, callback: Callable[[], None]) -> None:
        """Calls `callback` (under the table lock: it must be quick) after every change
        that may admit a waiting insert or sample. The asynchronous server waits this way."""
        self._watchers.append(callback)

    def unwatch(self, callback: Callable[[], None]) -> None:
        self._watchers.remove(callback)

    def log_samples(self, record: Callable[[str, int], None]) -> None:
        """Has every sampled batch recorded as `record(table name, items)` (under the
        table lock, before it is counted and returned): a write-ahead log keeps the sample
        count this way. An error `record` raises fails the sample."""
        self._sample_log = record

    def _changed(self) -> None:
        self._cond.notify_all()
        for callback in self._watchers:
            callback()

    def not_admitted(self, what: str, timeout: float) -> RateLimitTimeout:
        """The error for a `what` ("insert", "sample") that waited `timeout` seconds in vain."""
        return RateLimitTimeout(
            f"table '{self.name}': {what} not admitted within {timeout:.3g} s "
            f"(size {self.size}, {self.rate_limiter.describe()})"
        )

    def _wait(self, admitted: Callable[[], bool], timeout: Optional[float], what: str) -> float:
        """Sleeps on the condition (lock released) until `admitted()`; returns seconds waited."""
        if admitted():
            return 0.0
        start = time.monotonic()
        deadline = None if timeout is None else start + timeout
        while not admitted():
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                raise self.not_admitted(what, timeout or 0.0)
            self._cond.wait(1.0 if remaining is None else min(remaining, 1.0))
        return time.monotonic() - start

    # ---------------------------------------------------------------- insert

    def prepare(self, batch: Batch) -> PreparedInsert:
        """Validates a batch against the signature and the reserved columns (no lock taken)."""
        by_priority = isinstance(self.sampler, Prioritized)
        return prepare_insert(batch, self.signature, table=self.name, by_priority=by_priority)

    def insert_admitted(self) -> bool:
        """Whether the rate limiter admits an insert now; the caller holds `lock`."""
        s = self.stats
        return self.rate_limiter.insert_allowed(inserts=s.inserts, samples=s.samples)

    def store(self, prepared: PreparedInsert, *, writer: str = "") -> int:
        """Stores a prepared batch (evicting per the remover), without asking the rate
        limiter; the caller holds `lock` and has asked it. Returns items stored."""
        if prepared.n == 0:
            return 0
        self._store(prepared.batch, prepared.n, prepared.priority, prepared.stream, writer)
        self.stats.inserts += prepared.n
        self._changed()
        return prepared.n

    def insert(
        self,
        batch: Batch,
        *,
        timeout: Optional[float] = None,
        writer: str = "",
        before_store: Optional[Callable[[], None]] = None,
        rate_limited: bool = True,
    ) -> int:
        """Validates and stores a batch, blocking while the rate limiter says wait; returns
        items stored. `before_store` runs under the table lock once the batch is admitted,
        right before its rows go in, so a write-ahead log sees inserts in exactly the order
        the table applies them; if it raises, nothing is stored. `rate_limited=False` is
        for replaying a log on restart."""
        prepared = self.prepare(batch)
        if prepared.n == 0:
            return 0
        with self._cond:
            if rate_limited:
                self.stats.insert_blocked_s += self._wait(self.insert_admitted, timeout, "insert")
            if before_store is not None:
                before_store()
            return self.store(prepared, writer=writer)

    def _store(
        self,
        batch: Batch,
        n: int,
        priority: Optional[np.ndarray],
        stream: np.ndarray,
        writer: str,
    ) -> None:
        skip = max(0, n - self.max_size)  # a batch larger than the table keeps its newest rows
        keys, rows, evicted = self.slots.allocate(n - skip)
        for column, array in self._columns.items():
            array[rows] = batch[column][skip:]
        if self.max_times_sampled:
            self._times_sampled[rows] = 0
        if isinstance(self.sampler, Prioritized):
            self.sampler.set(evicted, np.zeros(len(evicted)))
            fresh = np.full(len(rows), self.sampler.max_priority)
            self.sampler.set(rows, fresh if priority is None else priority[skip:])
        if self.max_sequence_length > 1:
            ended = np.zeros(n - skip, dtype=bool)
            for column in self._ends:
                ended |= batch[column][skip:].astype(bool)
            self._links.link(keys, rows, stream[skip:], ended, writer)

    # ---------------------------------------------------------------- sample

    def sampled_bytes(self, batch_size: int, sequence_length: int = 1) -> int:
        """Bytes of the columns a sample of `batch_size` items returns (`sampled_bytes`)."""
        return sampled_bytes(self._item_bytes, batch_size, sequence_length)

    def check_sample(self, batch_size: int, sequence_length: int) -> None:
        """Refuses a sample request this table can never serve, before anything is drawn."""
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if not 1 <= sequence_length <= self.max_sequence_length:
            raise ValueError(
                f"sequence_length {sequence_length} is outside [1, {self.max_sequence_length}] "
                f"(table '{self.name}' max_sequence_length)"
            )

    def _try_draw(self, batch_size: int, k: int) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """Start rows (windows) and probabilities if the rate limiter admits a sample now and
        enough complete windows were found; the caller holds `lock`."""
        s = self.stats
        if not self.rate_limiter.sample_allowed(
            size=self.size, inserts=s.inserts, samples=s.samples
        ):
            return None
        return self._links.draw(self.sampler, self._rng, batch_size, k) if self.size else None

    def _take(
        self, drawn: tuple[np.ndarray, np.ndarray], batch_size: int, k: int
    ) -> tuple[Batch, int]:
        """Gathers drawn windows and counts them as sampled; the caller holds `lock` and
        reports the change (`_changed`). Returns the columns and the table size to weigh
        them by."""
        window_rows, _ = drawn
        out = self._gather(window_rows, k)
        if self._sample_log is not None:
            self._sample_log(self.name, batch_size)
        self._count_samples(window_rows[:, 0])
        self.stats.samples += batch_size
        return out, max(self.size, 1)

    def _weigh(self, out: Batch, probabilities: np.ndarray, size: int, batch_size: int) -> Batch:
        """Adds `_weight` and `_probability` (outside the lock) to `out`, which stacks
        batches of `batch_size` items: importance weights are normalised per batch."""
        if isinstance(self.sampler, Prioritized):
            out["_weight"] = np.concatenate(
                [
                    self.sampler.importance_weights(probabilities[i : i + batch_size], size)
                    for i in range(0, len(probabilities), batch_size)
                ]
            )
        else:
            out["_weight"] = np.ones(len(probabilities), dtype=np.float32)
        out["_probability"] = probabilities
        return out

    def try_sample(
        self,
        batch_size: int,
        *,
        sequence_length: int = 1,
        blocked_s: float = 0.0,
        blocking: bool = True,
    ) -> Optional[Batch]:
        """One attempt at `sample`: the batch if the rate limiter admits it now, else None
        (never waits on the limiter). `blocked_s` is the time the caller already waited,
        for the stats.

        Raises:
            LockBusy: `blocking` is False and the table lock is held.
        """
        sampled = self.try_sample_batches(
            batch_size, 1, sequence_length=sequence_length, blocked_s=blocked_s, blocking=blocking
        )
        return None if sampled is None else sampled[0]

    def try_sample_batches(
        self,
        batch_size: int,
        count: int,
        *,
        sequence_length: int = 1,
        blocked_s: float = 0.0,
        blocking: bool = True,
    ) -> Optional[tuple[Batch, int]]:
        """Up to `count` batches under one hold of the lock, as `count` calls of
        `try_sample` in a row would draw them: the rate limiter admits (and counts) each
        batch on its own, and the first batch it refuses ends them. Returns the batches
        stacked (batch i in rows [i * batch_size, (i + 1) * batch_size)) and how many;
        None while the limiter admits none. Never waits on the limiter.

        Raises:
            LockBusy: `blocking` is False and the table lock is held.
        """
        self.check_sample(batch_size, sequence_length)
        if not self._cond.acquire(blocking=blocking):
            raise LockBusy(f"table '{self.name}'")
        try:
            if sequence_length == 1 and self._draws_independent:
                drawn = self._draw_admitted(batch_size, count)
            else:
                drawn = self._draw_one_by_one(batch_size, count, sequence_length)
            if drawn is None:
                return None
            self.stats.sample_blocked_s += blocked_s
            size = max(self.size, 1)
            self._changed()  # once: waiting inserts re-check the limiter once
        finally:
            self._cond.release()
        out, probabilities, n = drawn
        return self._weigh(out, probabilities, size, batch_size), n

    def _draw_admitted(
        self, batch_size: int, count: int
    ) -> Optional[tuple[Batch, np.ndarray, int]]:
        """The batches the limiter admits, drawn and gathered at once: with independent
        draws and no item removed by sampling, n batches drawn together are n batches
        drawn in a row. Each is admitted and counted on its own; the caller holds `lock`."""
        s, n = self.stats, 0
        while (
            n < count
            and self.size
            and self.rate_limiter.sample_allowed(
                size=self.size, inserts=s.inserts, samples=s.samples + n * batch_size
            )
        ):
            n += 1
        if n == 0:
            return None
        rows, probabilities = self.sampler.sample(self.slots, self._rng, n * batch_size)
        out = self._gather(rows[:, None], 1)
        for _ in range(n):
            if self._sample_log is not None:
                self._sample_log(self.name, batch_size)
            s.samples += batch_size
        return out, probabilities, n

    def _draw_one_by_one(
        self, batch_size: int, count: int, k: int
    ) -> Optional[tuple[Batch, np.ndarray, int]]:
        """Up to `count` batches, each drawn after the one before was counted (a fifo or
        lifo sampler, items used up by `max_times_sampled`, windows); the caller holds
        `lock`."""
        taken: list[tuple[Batch, np.ndarray]] = []
        while len(taken) < count:
            drawn = self._try_draw(batch_size, k)
            if drawn is None:
                break
            out, _ = self._take(drawn, batch_size, k)
            taken.append((out, drawn[1]))
        if not taken:
            return None
        out = stack_batches([out for out, _ in taken])
        return out, np.concatenate([p for _, p in taken]), len(taken)

    def sample(
        self, batch_size: int, *, sequence_length: int = 1, timeout: Optional[float] = None
    ) -> Batch:
        """Draws `batch_size` items (windows of `sequence_length` steps if > 1), blocking
        while the rate limiter says wait.

        Returns the data columns (shaped [B, ...] or [B, k, ...]) plus `_key`, the
        sampling `_probability` of each (start) item, and its importance `_weight`; for
        windows, `_valid` [B, k]: which steps are the episode's (after an episode's end its
        last step is repeated).
        """
        k = sequence_length
        self.check_sample(batch_size, k)
        drawn: list[tuple[np.ndarray, np.ndarray]] = []

        def admitted() -> bool:
            found = self._try_draw(batch_size, k)
            drawn[:] = [found] if found is not None else []
            return bool(drawn)

        with self._cond:
            self.stats.sample_blocked_s += self._wait(admitted, timeout, "sample")
            out, size = self._take(drawn[0], batch_size, k)
            self._changed()
        return self._weigh(out, drawn[0][1], size, batch_size)

    def _gather(self, window_rows: np.ndarray, k: int) -> Batch:
        flat = window_rows.reshape(-1) if k > 1 else window_rows[:, 0]
        records = np.take(self._records, flat, axis=0)  # one gather of whole items
        out = {c: np.ascontiguousarray(field.of(records)) for c, field in self._fields.items()}
        keys = self.slots.keys_of(flat).astype(np.uint64)
        if k > 1:
            out = {c: a.reshape(len(window_rows), k, *a.shape[1:]) for c, a in out.items()}
            keys = keys.reshape(len(window_rows), k)
            # A step repeating the one before is padding after its episode's end.
            valid = np.ones(window_rows.shape, dtype=bool)
            valid[:, 1:] = window_rows[:, 1:] != window_rows[:, :-1]
            out["_valid"] = valid
        out["_key"] = keys
        return out

    def _count_samples(self, start_rows: np.ndarray) -> None:
        if not self.max_times_sampled:
            return
        np.add.at(self._times_sampled, start_rows, 1)
        used_up = np.unique(start_rows[self._times_sampled[start_rows] >= self.max_times_sampled])
        if len(used_up):
            self.slots.remove(used_up)
            if isinstance(self.sampler, Prioritized):
                self.sampler.set(used_up, np.zeros(len(used_up)))

    # ------------------------------------------------------------- priorities

    def update_priorities(self, keys: np.ndarray, priorities: np.ndarray) -> int:
        """Sets new priorities by item key; keys no longer stored are skipped."""
        if not isinstance(self.sampler, Prioritized):
            raise ValueError(f"table '{self.name}' samples {self.sampler.name}ly, not by priority")
        if keys.shape != priorities.shape:
            raise ValueError(f"{len(keys)} keys but {len(priorities)} priorities")
        if not np.all(np.isfinite(priorities) & (priorities >= 0)):
            raise ValueError("priorities must be finite and >= 0")
        with self._cond:
            live = self.slots.live(keys)
            self.sampler.set(self.slots.rows_of(keys[live]), priorities[live])
            self._changed()
        return int(live.sum())

    # ------------------------------------------------------------- checkpoint

    def snapshot(self) -> dict[str, Any]:
        """Copies the table's state; the caller holds `lock` (see ReplayCore.checkpoint)."""
        keys = self.slots.live_keys()
        rows = self.slots.rows_of(keys)
        state: dict[str, Any] = {f"col/{c}": a[rows] for c, a in self._columns.items()}
        state["keys"] = keys
        state["times_sampled"] = self._times_sampled[rows] if self.max_times_sampled else None
        state["priorities"] = (
            self.sampler.priorities(rows) if isinstance(self.sampler, Prioritized) else None
        )
        next_key = self._links.next_key[rows] if self.max_sequence_length > 1 else None
        state["next_key"] = next_key
        state["meta"] = {
            "next_key": int(self.slots.next_key),
            "inserts": self.stats.inserts,
            "samples": self.stats.samples,
            "max_priority": getattr(self.sampler, "max_priority", None),
            "streams": [[w, s, k, e] for (w, s), (k, e) in self._links.streams.items()],
        }
        return state

    def restore(self, state: dict[str, Any]) -> None:
        """Loads a `snapshot` into this (empty) table."""
        meta = state["meta"]
        with self._cond:
            rows = self.slots.restore(np.asarray(state["keys"], np.int64), meta["next_key"])
            for column, array in self._columns.items():
                array[rows] = state[f"col/{column}"]
            if self.max_times_sampled and state.get("times_sampled") is not None:
                self._times_sampled[rows] = state["times_sampled"]
            if isinstance(self.sampler, Prioritized) and state.get("priorities") is not None:
                self.sampler.set(rows, np.asarray(state["priorities"]))
                self.sampler.max_priority = meta["max_priority"] or 1.0
            if self.max_sequence_length > 1 and state.get("next_key") is not None:
                self._links.next_key[rows] = state["next_key"]
            self._links.streams = {(w, s): (k, e) for w, s, k, e in meta["streams"]}
            self.stats.inserts, self.stats.samples = meta["inserts"], meta["samples"]

    @property
    def lock(self) -> threading.Condition:
        return self._cond
