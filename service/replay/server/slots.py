"""Slot bookkeeping for a table: which storage rows hold which item keys.

Two strategies behind one interface:

* `RingSlots` (FIFO eviction, items never removed early): item k lives in row
  ``k % capacity``; keys need no storage, so memory is the columns alone.
* `FreeListSlots` (LIFO eviction, or removal after `max_times_sampled`): rows are
  recycled through a free list and each row records its key.
"""

from __future__ import annotations

from collections import deque

import numpy as np

EMPTY = np.iinfo(np.int64).max


class RingSlots:
    """Keys [head, next) live in rows ``key % capacity``; the oldest are evicted first."""

    removes_items = False

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.head = 0
        self.next_key = 0

    @property
    def size(self) -> int:
        return self.next_key - self.head

    def allocate(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Makes room for n <= capacity items; returns (keys, rows, evicted rows)."""
        evict = max(0, self.size + n - self.capacity)
        evicted = np.arange(self.head, self.head + evict, dtype=np.int64) % self.capacity
        self.head += evict
        keys = np.arange(self.next_key, self.next_key + n, dtype=np.int64)
        self.next_key += n
        return keys, keys % self.capacity, evicted

    def rows_of(self, keys: np.ndarray) -> np.ndarray:
        return keys % self.capacity

    def keys_of(self, rows: np.ndarray) -> np.ndarray:
        base = self.head - self.head % self.capacity
        keys = base + rows
        return np.where(keys < self.head, keys + self.capacity, keys)

    def live(self, keys: np.ndarray) -> np.ndarray:
        return (keys >= self.head) & (keys < self.next_key)

    def uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return (self.head + rng.integers(0, self.size, size=n)) % self.capacity

    def oldest(self, n: int) -> np.ndarray:
        return (self.head + np.arange(n) % self.size) % self.capacity

    def newest(self, n: int) -> np.ndarray:
        return (self.next_key - 1 - np.arange(n) % self.size) % self.capacity

    def live_keys(self) -> np.ndarray:
        return np.arange(self.head, self.next_key, dtype=np.int64)

    def remove(self, rows: np.ndarray) -> None:
        raise NotImplementedError("ring slots never remove items early")

    def restore(self, keys: np.ndarray, next_key: int) -> np.ndarray:
        if len(keys) and not np.array_equal(keys, np.arange(keys[0], keys[0] + len(keys))):
            raise ValueError("a FIFO ring checkpoint must hold consecutive keys")
        self.head = int(keys[0]) if len(keys) else next_key
        self.next_key = next_key
        return self.rows_of(keys)


class FreeListSlots:
    """Rows recycled through a free list; eviction order kept as a deque of keys."""

    removes_items = True

    def __init__(self, capacity: int, *, evict_newest: bool) -> None:
        self.capacity = capacity
        self.evict_newest = evict_newest
        self.keys = np.full(capacity, EMPTY, dtype=np.int64)
        self._free = list(range(capacity - 1, -1, -1))  # pop() hands out low rows first
        self._row_of: dict[int, int] = {}
        self._order: deque[int] = deque()  # insertion order, with keys removed early left in
        self.next_key = 0
        self._high_water = 0

    @property
    def size(self) -> int:
        return len(self._row_of)

    def _evict_one(self) -> int:
        while True:
            key = self._order.pop() if self.evict_newest else self._order.popleft()
            row = self._row_of.pop(key, None)
            if row is not None:
                self.keys[row] = EMPTY
                return row

    def allocate(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        evicted = [self._evict_one() for _ in range(max(0, self.size + n - self.capacity))]
        self._free.extend(evicted)
        rows = np.array([self._free.pop() for _ in range(n)], dtype=np.int64)
        keys = np.arange(self.next_key, self.next_key + n, dtype=np.int64)
        self.next_key += n
        self._place(keys, rows)
        return keys, rows, np.array(evicted, dtype=np.int64)

    def _place(self, keys: np.ndarray, rows: np.ndarray) -> None:
        self.keys[rows] = keys
        self._row_of.update(zip(keys.tolist(), rows.tolist(), strict=True))
        self._order.extend(keys.tolist())
        if len(rows):
            self._high_water = max(self._high_water, int(rows.max()) + 1)

    def rows_of(self, keys: np.ndarray) -> np.ndarray:
        get = self._row_of.get
        return np.array([get(k, -1) for k in keys.tolist()], dtype=np.int64)

    def keys_of(self, rows: np.ndarray) -> np.ndarray:
        keys: np.ndarray = self.keys[rows]
        return keys

    def live(self, keys: np.ndarray) -> np.ndarray:
        return np.array([k in self._row_of for k in keys.tolist()], dtype=bool)

    def uniform(self, rng: np.random.Generator, n: int) -> np.ndarray:
        live_fraction = self.size / max(self._high_water, 1)
        if live_fraction < 0.25:  # rejection would be slow: draw from the live rows directly
            return rng.choice(np.flatnonzero(self.keys[: self._high_water] != EMPTY), size=n)
        picked = np.empty(0, dtype=np.int64)
        while len(picked) < n:  # rejection sampling stays uniform over live rows
            candidates = rng.integers(0, self._high_water, size=2 * n)
            picked = np.concatenate([picked, candidates[self.keys[candidates] != EMPTY]])
        return picked[:n]

    def _in_order(self, n: int, newest: bool) -> np.ndarray:
        found: list[int] = []
        order = reversed(self._order) if newest else iter(self._order)
        for key in order:
            row = self._row_of.get(key)
            if row is not None:
                found.append(row)
                if len(found) == min(n, self.size):
                    break
        return np.resize(np.array(found, dtype=np.int64), n)

    def oldest(self, n: int) -> np.ndarray:
        return self._in_order(n, newest=False)

    def newest(self, n: int) -> np.ndarray:
        return self._in_order(n, newest=True)

    def live_keys(self) -> np.ndarray:
        return np.array(sorted(self._row_of), dtype=np.int64)

    def remove(self, rows: np.ndarray) -> None:
        for row in np.unique(rows).tolist():
            key = int(self.keys[row])
            if key != EMPTY:
                del self._row_of[key]
                self.keys[row] = EMPTY
                self._free.append(row)
        if len(self._order) > 2 * self.size + 1024:  # drop the keys removed early
            self._order = deque(k for k in self._order if k in self._row_of)

    def restore(self, keys: np.ndarray, next_key: int) -> np.ndarray:
        rows = np.array([self._free.pop() for _ in range(len(keys))], dtype=np.int64)
        self._place(keys, rows)
        self.next_key = next_key
        return rows
