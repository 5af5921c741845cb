"""A run's replay folder across `--resume`: reused when it holds the resumed run's table,
else moved aside (never deleted or changed) so that the run refills a fresh table.

    RUN_DIR/replay          the replay server's checkpoint folder (checkpoints and log)
    RUN_DIR/replay.json     the table specs served from it, and the run's env steps when
                            its tables were empty (`env_steps_before`)
    RUN_DIR/replay.stale-N  a folder a resume could not use, with its replay.json
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from graft.replay_host.process import FolderRefused
from graft.replay_host.shards import RunReplay
from service.replay.client import ReplayClient
from service.replay.server.folder_lock import FolderInUse, lock_folder

FOLDER = "replay"
RECORD = "replay.json"

FREE_WITHIN_S = 30.0
"""How long a folder may stay locked by the killed run's server (it writes a last
checkpoint once it sees its launcher gone) before a resume gives up."""


@dataclass(frozen=True)
class Restored:
    """What a resumed run's table holds after its server restored the folder."""

    inserts: int
    samples: int
    """Items sampled (a batch of B counts B), as the rate limiter counts them."""
    size: int
    env_steps_before: int
    """The run's env steps when this table was empty (0 unless an earlier resume refilled)."""

    @property
    def env_steps(self) -> int:
        """The run's env steps this table accounts for: each insert is one."""
        return self.env_steps_before + self.inserts


def _record(run_dir: Path, tables: list[dict[str, Any]], env_steps_before: int) -> None:
    path, tmp = run_dir / RECORD, run_dir / f".{RECORD}.tmp"
    tmp.write_text(json.dumps({"tables": tables, "env_steps_before": env_steps_before}, indent=1))
    os.replace(tmp, path)


def _mismatch(run_dir: Path, tables: list[dict[str, Any]]) -> tuple[Optional[str], int]:
    """Why RUN_DIR/replay cannot serve `tables` (None: it can), and its env_steps_before."""
    path = run_dir / RECORD
    if not path.is_file():
        return f"has no {RECORD} saying which tables it holds", 0
    try:
        record = json.loads(path.read_text())
        recorded, before = record["tables"], int(record["env_steps_before"])
    except (ValueError, KeyError, TypeError) as error:
        return f"has an unreadable {RECORD} ({type(error).__name__}: {error})", 0
    wanted = json.loads(json.dumps(tables))  # as JSON reads it back: lists, not tuples
    names = ([t.get("name") for t in recorded], [t["name"] for t in wanted])
    if names[0] != names[1]:
        return f"holds tables {names[0]}, not this run's {names[1]}", before
    for old, new in zip(recorded, wanted, strict=True):
        changed = sorted(k for k in {*old, *new} if old.get(k) != new.get(k))
        if changed:
            shown = "; ".join(f"{k} {old.get(k)!r} is now {new.get(k)!r}" for k in changed)
            return f"holds table '{new['name']}' under another spec ({shown})", before
    return None, before


def reusable(run_dir: Path, tables: list[dict[str, Any]]) -> bool:
    """Whether RUN_DIR/replay is there and recorded as holding `tables`: a resume then
    expects to restore it (the server may still refuse it)."""
    return (run_dir / FOLDER).is_dir() and _mismatch(run_dir, tables)[0] is None


def _until_free(folder: Path) -> None:
    """Waits (up to FREE_WITHIN_S) until no server holds `folder`."""
    deadline = time.monotonic() + FREE_WITHIN_S
    while True:
        try:
            lock_folder(folder).close()
            return
        except FolderInUse:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def _set_aside(run_dir: Path, reason: str, say: Callable[[str], None]) -> None:
    """Renames RUN_DIR/replay (and its record) to the first free `replay.stale-<n>`."""
    folder = run_dir / FOLDER
    _until_free(folder)
    n = 1
    while (run_dir / f"{FOLDER}.stale-{n}").exists():
        n += 1
    target = run_dir / f"{FOLDER}.stale-{n}"
    folder.rename(target)
    if (run_dir / RECORD).exists():
        (run_dir / RECORD).rename(target / RECORD)
    say(f"--resume: {folder} {reason}; moved it to {target}, refilling a fresh table")


def open_replay(
    start: Callable[[], RunReplay],
    *,
    run_dir: Path,
    tables: list[dict[str, Any]],
    token: Optional[str],
    resumed_env_steps: Optional[int],
    reproducible: bool = False,
    shards: int = 1,
    say: Callable[[str], None] = print,
) -> tuple[RunReplay, Optional[Restored]]:
    """Starts the run's replay server on RUN_DIR/replay; with `resumed_env_steps` (the
    learner checkpoint's env steps), on the folder the run left when it holds its table.

    The folder is moved aside, with one line through `say`, when its record names another
    table spec, when the server refuses it (it cannot be restored whole), when its table
    holds fewer inserts than the learner checkpoint had seen (data went missing), or for a
    `reproducible` run (its lock-step schedule starts from an empty table), and for a run
    of several `shards` (a resume restores one server's folder only).

    Returns:
        The server, and what its table restored (None: a fresh table that must refill).
    """
    folder = run_dir / FOLDER
    reason, before = None, 0
    if resumed_env_steps is not None:
        reason, before = _mismatch(run_dir, tables)
        if reason is None and reproducible:
            reason = "is not reused by a reproducible run (its lock-step schedule starts empty)"
        if reason is None and shards > 1:
            reason = f"is not reused by a run of {shards} replay shards (only a single server's is)"
    if resumed_env_steps is not None and folder.exists() and reason is None:
        _until_free(folder)  # the killed run's server may still be writing its last checkpoint
        try:
            replay = start()
        except FolderRefused as refused:
            reason = f"could not be restored ({refused})"
        else:
            restored = _restored(replay, tables[0]["name"], token, before)
            if restored.env_steps >= resumed_env_steps:
                return replay, restored
            replay.stop()
            reason = (
                f"holds {restored.inserts:,} inserts, fewer than the "
                f"{resumed_env_steps - before:,} the learner checkpoint had seen"
            )
    if folder.exists() and resumed_env_steps is not None:
        _set_aside(run_dir, reason or "", say)
    elif resumed_env_steps is not None:
        say(f"--resume: {run_dir} has no {FOLDER} folder to reuse; refilling a fresh table")
    _record(run_dir, tables, resumed_env_steps or 0)
    return start(), None


def _restored(replay: RunReplay, table: str, token: Optional[str], before: int) -> Restored:
    client = ReplayClient(replay.addresses[0], token=token, max_retries=5)
    try:
        info = next(t for t in client.info() if t.name == table)
    finally:
        client.close()
    return Restored(info.inserts, info.samples, info.size, before)
