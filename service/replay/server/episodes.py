"""Episodes in a table: each stored step's successor in its (writer, `_stream`) episode,
and the k-step windows drawn along those links.

A step that is `terminated` or `truncated` has no successor, so a window never crosses
an episode boundary. A window that reaches its episode's end before k steps is complete
all the same: its last step is repeated to fill it (`_valid` says which steps are the
episode's), so the last k − 1 steps of an episode, and episodes shorter than k, start
windows too. A single transition is simply the k=1 window.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from service.replay.server.samplers import Sampler, Slots
from service.replay.server.slots import EMPTY

ENDED = EMPTY - 1
"""`next_key` of a step that ended its episode: it has no successor, and will get none."""


class EpisodeLinks:
    """Successor links of one table's steps; kept only when `enabled` (windows longer
    than one step). The caller holds the table lock."""

    def __init__(self, slots: Slots, max_size: int, *, enabled: bool) -> None:
        self._slots = slots
        self.next_key = np.full(max_size if enabled else 0, EMPTY, np.int64)
        """Per row, the key of the next step of its episode (EMPTY: none, or not yet)."""
        self.streams: dict[tuple[str, int], tuple[int, bool]] = {}
        """Per (writer, stream), the key of its latest step and whether that step ended
        its episode."""

    def link(
        self, keys: np.ndarray, rows: np.ndarray, stream: np.ndarray, ended: np.ndarray, writer: str
    ) -> None:
        """Points each step at its successor in the same (writer, stream) episode."""
        self.next_key[rows] = np.where(ended, ENDED, EMPTY)
        for s in np.unique(stream).tolist():
            at = np.flatnonzero(stream == s)
            linked = ~ended[at[:-1]]
            self.next_key[rows[at[:-1]][linked]] = keys[at[1:]][linked]
            previous = self.streams.get((writer, s))
            if previous is not None and not previous[1]:
                prev_key = np.array([previous[0]])
                if self._slots.live(prev_key)[0]:
                    self.next_key[self._slots.rows_of(prev_key)] = keys[at[0]]
            self.streams[(writer, s)] = (int(keys[at[-1]]), bool(ended[at[-1]]))

    def windows(self, start_rows: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Rows [B, k] of the windows starting at `start_rows`, and which are complete: k
        steps of one episode, or its steps to its end with the last one repeated after it.
        A window whose next step is not stored (not inserted yet, or evicted) is not."""
        window = np.empty((len(start_rows), k), dtype=np.int64)
        window[:, 0] = start_rows
        complete = np.ones(len(start_rows), dtype=bool)
        ended = np.zeros(len(start_rows), dtype=bool)  # the episode ended inside the window
        for j in range(1, k):
            successor = self.next_key[window[:, j - 1]]
            ended |= successor == ENDED
            follows = complete & ~ended & (successor != EMPTY)
            follows[follows] = self._slots.live(successor[follows])
            complete &= ended | follows
            window[:, j] = window[:, j - 1]  # padding after the episode's end
            window[follows, j] = self._slots.rows_of(successor[follows])
        return window, complete

    def draw(
        self, sampler: Sampler, rng: np.random.Generator, batch_size: int, k: int
    ) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """Rows [B, k] of `batch_size` complete windows and the sampling probability of
        each start item; None if too few complete windows were found."""
        rows, probabilities = sampler.sample(self._slots, rng, batch_size)
        if k == 1:
            return rows[:, None], probabilities
        found_rows, found_p, have = [], [], 0
        for _ in range(32):  # rejection keeps the sampler's distribution over complete windows
            window, complete = self.windows(rows, k)
            found_rows.append(window[complete])
            found_p.append(probabilities[complete])
            have += int(complete.sum())
            if have >= batch_size:
                return np.concatenate(found_rows)[:batch_size], np.concatenate(found_p)[:batch_size]
            rows, probabilities = sampler.sample(self._slots, rng, batch_size)
        return None
