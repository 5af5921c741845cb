"""What a table may fill at its max_size, worked out before anything is allocated, and
the server's memory budget the tables share (service/memory.py).

numpy allocates a table's records lazily: a table larger than the memory is accepted,
fills as items arrive, and the kernel's OOM killer ends the server. Refusing it at start,
in one line naming the table, the bytes and the budget, is the only honest answer.
"""

from __future__ import annotations

import math
from typing import Optional

from service.memory import MemoryBudget, gib
from service.replay.server.records import record_layout
from service.replay.server.signature import Signature

FREE_LIST_BYTES_PER_ITEM = 8 + 8 + 36 + 104
"""A free-list table's index per item: its key (int64), its place in the eviction deque,
the free list's Python int (pointer and object) and its entry in the row dict."""


def item_bytes(
    signature: Signature, *, max_times_sampled: int, max_sequence_length: int, remover: str
) -> int:
    """Bytes one item takes at most: its record, its sample count, its episode link and
    its place in the free list (the arrays a Table sizes by max_size)."""
    _, record = record_layout(signature)
    index = 4 if max_times_sampled else 0
    index += 8 if max_sequence_length > 1 else 0
    if not (remover == "fifo" and max_times_sampled == 0):
        index += FREE_LIST_BYTES_PER_ITEM
    return record + index


def table_bytes(max_size: int, per_item: int, *, prioritized: bool) -> int:
    """A table's bytes at max_size: its items and, prioritized, its sum-tree (float64 over
    the next power of two of leaves, twice)."""
    tree = 2 * 8 * (1 << max(0, math.ceil(math.log2(max(max_size, 1))))) if prioritized else 0
    return max_size * per_item + tree


def capped_size(name: str, max_size: int, per_item: int, max_bytes: Optional[int]) -> int:
    """The table's capacity in items: max_size, or fewer where `max_bytes` holds fewer
    (the remover then evicts on bytes).

    Raises:
        ValueError: max_bytes is not a positive integer, or holds no item.
    """
    if max_bytes is None:
        return max_size
    if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or max_bytes < 1:
        raise ValueError(f"table '{name}' max_bytes={max_bytes!r} must be an integer >= 1")
    if max_bytes < per_item:
        raise ValueError(
            f"table '{name}' max_bytes={max_bytes} holds no item: one takes {per_item} B"
        )
    return min(max_size, max_bytes // per_item)


def sampled_bytes(per_item: int, batch_size: int, sequence_length: int = 1) -> int:
    """Bytes of the columns a sample of `batch_size` items (windows of `sequence_length`)
    returns: data and `_key` per step, `_probability` and `_weight` per item (the encoded
    payload adds a little)."""
    return batch_size * (sequence_length * (per_item + 8) + 8 + 8)


class MemoryLedger:
    """The tables' worst-case bytes against one budget, claimed table by table."""

    def __init__(self, budget: MemoryBudget) -> None:
        self.budget = budget
        self.claimed = 0

    def claim(self, name: str, max_size: int, per_item: int, need: int) -> None:
        """Adds a table's worst case.

        Raises:
            ValueError: it does not fit in what the tables before it left, e.g.
                ``table 'frames' needs 394.2 GiB at max_size 20000000 (21176 B an item),
                over the memory budget 21.2 GiB (...)``.
        """
        if self.claimed + need > self.budget.bytes:
            before = f" with {gib(self.claimed)} of tables before it" if self.claimed else ""
            raise ValueError(
                f"table '{name}' needs {gib(need)} at max_size {max_size} ({per_item} B an "
                f"item){before}, over the memory budget {self.budget}; lower max_size, give "
                "the table a max_bytes, or set --max-memory"
            )
        self.claimed += need
