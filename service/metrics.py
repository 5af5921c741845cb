"""Run metrics: namespaced scalars to TensorBoard and a long-format CSV; the learning curve."""

from __future__ import annotations

import csv
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Optional, TextIO

import numpy as np


class MetricsLogger:
    """Appends `wall_s, env_steps, updates, key, value` rows; mirrors them to TensorBoard.

    With ``wall_clock=False`` (reproducible mode) metrics.csv holds only what a run
    computes, `env_steps, updates, key, value`, so two runs of one seed compare byte for
    byte; wall-clock measurements (the `perf/` keys, and every row's time) go to
    timing.csv beside it.
    """

    FIELDS = ("wall_s", "env_steps", "updates", "key", "value")
    TIMING_PREFIX = "perf/"
    """Keys measured on the wall clock (rates, waiting shares), never reproducible."""

    def __init__(self, run_dir: Path, *, tensorboard: bool = True, wall_clock: bool = True) -> None:
        run_dir.mkdir(parents=True, exist_ok=True)
        self.csv_path = run_dir / "metrics.csv"
        self.wall_clock = wall_clock
        self._file, self._csv = _open_csv(self.csv_path, self.FIELDS[int(not wall_clock) :])
        self._timing = None if wall_clock else _open_csv(run_dir / "timing.csv", self.FIELDS)
        """timing.csv (file, writer), in reproducible mode."""
        self._start = time.monotonic()
        self._tb = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(run_dir / "tensorboard"))

    def log(self, scalars: Mapping[str, float], *, env_steps: int, updates: int) -> None:
        """One call's rows go to each file in one `writerows`, so a signal (Ctrl-C, SIGTERM
        raise KeyboardInterrupt between bytecodes) cannot write some of them alone."""
        wall = round(time.monotonic() - self._start, 3)
        rows: list[tuple[Any, ...]] = []
        timing: list[tuple[Any, ...]] = []
        for key, value in scalars.items():
            row = (env_steps, updates, key, f"{float(value):.6g}")
            if self._timing is None:
                rows.append((wall, *row))
            elif key.startswith(self.TIMING_PREFIX):
                timing.append((wall, *row))
            else:
                rows.append(row)
        self._csv.writerows(rows)
        if self._timing is not None:
            self._timing[1].writerows(timing)
        if self._tb is not None:
            for key, value in scalars.items():
                self._tb.add_scalar(key, float(value), env_steps)
        try:
            self._file.flush()  # so a running job can be followed (tail, plots)
        except OSError as error:  # e.g. a full disk: say which file
            error.filename = error.filename or str(self.csv_path)
            raise
        if self._timing is not None:
            self._timing[0].flush()

    def close(self) -> None:
        self._file.close()
        if self._timing is not None:
            self._timing[0].close()
        if self._tb is not None:
            self._tb.close()


class PolicyLag:
    """How stale the data the learner samples is, from the columns every actor writes:
    `policy_version` (the weights an item was acted with; -1: the warm-up policy) and
    `acted_at` (wall-clock seconds when it was acted, by the actor's clock).

    `published` records when each version was published, so an item's lag at insert is
    the learner's version at `acted_at` minus the version it was acted with. Clocks of
    different nodes are assumed synchronised (NTP); an error of a few milliseconds
    shifts the lag of only the items acted right at a publish.
    """

    def __init__(self) -> None:
        self._times: list[float] = []
        self._versions: list[int] = []

    def published(self, version: int, wall: float) -> None:
        """Version `version` became the newest at wall-clock time `wall`."""
        self._times.append(wall)
        self._versions.append(version)

    def measure(
        self, batch: Mapping[str, np.ndarray], *, version: int, now: float
    ) -> dict[str, float]:
        """`perf/policy_lag` (mean versions behind at insert), its p90 and max, and the age
        of the sampled items (`perf/sample_age_versions`, `perf/sample_age_s`); warm-up items
        are left out. Empty when the batch lacks the columns or holds only warm-up items."""
        if "policy_version" not in batch or "acted_at" not in batch or not self._times:
            return {}
        acted_with = np.asarray(batch["policy_version"]).ravel()
        acted_at = np.asarray(batch["acted_at"]).ravel()
        mask = acted_with >= 0
        if not mask.any():
            return {}
        acted_with, acted_at = acted_with[mask], acted_at[mask]
        latest = np.searchsorted(self._times, acted_at, side="right") - 1
        newest_then = np.asarray(self._versions)[np.maximum(latest, 0)]
        # Clock skew can stamp an item just before the publish of the version it used.
        lag = np.maximum(newest_then - acted_with, 0)
        return {
            "perf/policy_lag": float(lag.mean()),
            "perf/policy_lag_p90": float(np.percentile(lag, 90)),
            "perf/policy_lag_max": float(lag.max()),
            "perf/sample_age_versions": float((version - acted_with).mean()),
            "perf/sample_age_s": float((now - acted_at).mean()),
        }


def _open_csv(path: Path, fields: tuple[str, ...]) -> tuple[TextIO, Any]:
    """A CSV file opened for appending, with its header when it is new.

    A run killed outright (SIGKILL) may leave the file empty (its header never flushed)
    or end in a torn row: the header is written again, the torn row cut off.
    """
    if path.exists():
        _cut_torn_row(path)
    new = not path.exists() or path.stat().st_size == 0
    file = path.open("a", newline="")
    writer = csv.writer(file)
    if new:
        writer.writerow(fields)
    return file, writer


def _cut_torn_row(path: Path) -> None:
    """Truncates `path` after its last complete line."""
    with path.open("rb+") as f:
        data = f.read()
        if data and not data.endswith(b"\n"):
            f.truncate(data.rfind(b"\n") + 1)


def read_metric(csv_path: Path, key: str) -> tuple[list[int], list[float]]:
    """Returns (env_steps, values) of one key from a metrics CSV."""
    steps, values = [], []
    with Path(csv_path).open() as f:
        for row in csv.DictReader(f):
            if row["key"] == key:
                steps.append(int(row["env_steps"]))
                values.append(float(row["value"]))
    return steps, values


def read_evaluations(csv_path: Path) -> list[tuple[int, float, float]]:
    """(env_steps, mean, std) of each evaluation in a metrics CSV, paired by env steps: a
    run stopped between an evaluation's two rows logged its mean alone, which is left out."""
    means: list[tuple[int, float]] = []
    std_at: dict[int, float] = {}
    with Path(csv_path).open() as f:
        for row in csv.DictReader(f):
            if row["key"] == "eval/return_mean":
                means.append((int(row["env_steps"]), float(row["value"])))
            elif row["key"] == "eval/return_std":
                std_at[int(row["env_steps"])] = float(row["value"])
    return [(x, m, std_at[x]) for x, m in means if x in std_at]


def plot_learning_curve(
    csv_path: Path,
    out_png: Path,
    *,
    title: str,
    reference: Optional[Mapping[str, float]] = None,
) -> None:
    """Draws evaluation return (± std) against env steps, with reference levels as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    evaluations = read_evaluations(csv_path)
    steps = [x for x, _, _ in evaluations]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(steps, [m for _, m, _ in evaluations], label="evaluation return", color="tab:blue")
    low = [m - s for _, m, s in evaluations]
    high = [m + s for _, m, s in evaluations]
    ax.fill_between(steps, low, high, alpha=0.2, color="tab:blue")
    for name, level in (reference or {}).items():
        ax.axhline(level, linestyle="--", color="tab:green", label=name)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(out_png, dpi=120)
    plt.close(fig)
