"""The run's replay: one supervised server, or N shards with a checkpoint folder each,
and the clients actors and the learner reach them with.

    replay = RunReplay(tables, shards=2, host=..., port=..., token=..., run_dir=run_dir, ...)
    actor_i = replay.writer(i)   # inserts into shard i mod N
    learner = replay.sampler()   # samples every shard
    replay.check()               # the supervisor: a dead shard restarts from its folder

One shard keeps the single-server layout (``RUN_DIR/replay``, ``RUN_DIR/replay.log``,
a plain `ReplayClient`); N shards use ``RUN_DIR/replay/shard-K`` and
``RUN_DIR/replay-shard-K.log``, and `ShardedReplayClient`.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Optional

import numpy as np

from graft.replay_host.supervised import SupervisedReplay
from service.replay.client import ReplayClient
from service.replay.errors import ReplayError
from service.replay.sharding import ShardedReplayClient


def _split(total: int, n: int, k: int) -> int:
    """Shard k's share of `total` items: the shares differ by at most one and sum to
    `total` (each at least 1: a minimum size of 0 would be refused)."""
    return max(total // n + (1 if k < total % n else 0), 1)


def shard_tables(tables: list[dict[str, Any]], n: int) -> list[list[dict[str, Any]]]:
    """Each shard's tables: the run's, with capacity, minimum size, error buffer and
    sample credit split N ways, and the sampler seeded per shard.

    Every shard's rate limiter sees only its own inserts and samples. It keeps the
    preset's samples per insert, and `SampleToInsertRatio`'s imbalance (inserts x ratio
    - samples - min_size x ratio + credit, held within +- error_buffer) is linear, so
    shares that sum to the preset's minimum size, credit and buffer make the shards'
    imbalances sum to the one server's: over the whole replay the ratio holds within
    the preset's buffer. Subtleties: each shard may overshoot its buffer by one batch
    (N batches in all, one server one); a shard fills its minimum size from its own
    writers only, so sampling starts when the first shard holds its share; and the
    learner must draw from the shards that admit samples (`ShardedSampleStream`), or
    a shard whose writers fell behind would hold the learner while others wait on it.
    """
    if n == 1:
        return [tables]
    shards = []
    for k in range(n):
        mine = []
        for table in tables:
            spec = copy.deepcopy(table)
            spec["max_size"] = -(-table["max_size"] // n)
            if "seed" in spec:
                spec["seed"] = int(np.random.SeedSequence([table["seed"], k]).generate_state(1)[0])
            limiter = spec.get("rate_limiter")
            if limiter is not None:
                if "min_size" in limiter:
                    limiter["min_size"] = _split(int(limiter["min_size"]), n, k)
                for key in ("error_buffer", "sample_credit"):
                    if key in limiter:
                        limiter[key] = limiter[key] / n
            mine.append(spec)
        shards.append(mine)
    return shards


class RunReplay:
    """The run's `shards` replay servers, each supervised (restarted on its port from
    its own checkpoint folder); `check()` and `restarts` as one `SupervisedReplay`.

    Args:
        tables: the run's tables (one server's; split by `shard_tables`).
        shards: how many servers.
        host: the address they bind.
        port: shard 0's port (0: each a free one); shard K listens on port + K.
        token: shared secret (beyond loopback), handed over in the environment.
        run_dir: the run folder, where checkpoint folders and logs go.
        checkpoint_every_s: seconds between each server's checkpoints.
        max_restarts: restarts allowed per shard.
        advertise: the host clients connect to (None: the address the server reports).
        max_retries: retries of a call that finds no server (waits out a restart).
    """

    def __init__(
        self,
        tables: list[dict[str, Any]],
        *,
        shards: int,
        host: str,
        port: int,
        token: Optional[str],
        run_dir: Path,
        checkpoint_every_s: float,
        max_restarts: int,
        advertise: Optional[str] = None,
        max_retries: int = 8,
    ) -> None:
        self.token, self.max_retries = token, max_retries
        self.servers: list[SupervisedReplay] = []
        try:
            for k, mine in enumerate(shard_tables(tables, shards)):
                folder, log = run_dir / "replay", run_dir / "replay.log"
                if shards > 1:
                    folder, log = folder / f"shard-{k}", run_dir / f"replay-shard-{k}.log"
                self.servers.append(
                    SupervisedReplay(
                        mine,
                        host=host,
                        port=port + k if port else 0,
                        token=token,
                        checkpoint_dir=folder,
                        checkpoint_every_s=checkpoint_every_s,
                        log_path=log,
                        max_restarts=max_restarts,
                    )
                )
        except BaseException:  # no server outlives a failed start
            self.stop()
            raise
        self.addresses = [
            s.address if advertise is None else f"{advertise}:{s.port}" for s in self.servers
        ]

    @property
    def restarts(self) -> int:
        """Restarts over all shards."""
        return sum(s.restarts for s in self.servers)

    def check(self) -> Optional[str]:
        """Restarts every dead shard; the lines saying so (None if all are alive).

        Raises:
            TooManyRestarts: a shard died more than its `max_restarts` allows.
        """
        lines = []
        for k, server in enumerate(self.servers):
            line = server.check()
            if line is not None:
                lines.append(line if len(self.servers) == 1 else f"shard {k}: {line}")
        return "; ".join(lines) if lines else None

    def writer(self, actor: int) -> ReplayClient | ShardedReplayClient:
        """The client actor `actor` inserts with: shard `actor` mod N."""
        if len(self.addresses) == 1:
            return self.sampler()
        return ShardedReplayClient(
            self.addresses, token=self.token, max_retries=self.max_retries,
            home=actor % len(self.addresses),
        )  # fmt: skip

    def sampler(self) -> ReplayClient | ShardedReplayClient:
        """The client the learner samples with (every shard)."""
        if len(self.addresses) == 1:
            return ReplayClient(self.addresses[0], token=self.token, max_retries=self.max_retries)
        return ShardedReplayClient(self.addresses, token=self.token, max_retries=self.max_retries)

    def inserts(self) -> list[int]:
        """Items each shard's tables received (-1 for a shard that does not answer)."""
        counts = []
        for address in self.addresses:
            client = ReplayClient(address, token=self.token, max_retries=0)
            try:
                counts.append(sum(t.inserts for t in client.info()))
            except ReplayError:  # a shard that died at the end: say so, do not fail the run
                counts.append(-1)
            finally:
                client.close()
        return counts

    def stop(self) -> None:
        for server in self.servers:
            server.stop()
