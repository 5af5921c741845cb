"""Run metrics: namespaced scalars to TensorBoard and a long-format CSV; the learning curve."""

from __future__ import annotations

import csv
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Optional, TextIO


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
        wall = round(time.monotonic() - self._start, 3)
        for key, value in scalars.items():
            row = (env_steps, updates, key, f"{float(value):.6g}")
            if self._timing is None:
                self._csv.writerow((wall, *row))
            elif key.startswith(self.TIMING_PREFIX):
                self._timing[1].writerow((wall, *row))
            else:
                self._csv.writerow(row)
            if self._tb is not None:
                self._tb.add_scalar(key, float(value), env_steps)
        self._file.flush()  # so a running job can be followed (tail, plots)
        if self._timing is not None:
            self._timing[0].flush()

    def close(self) -> None:
        self._file.close()
        if self._timing is not None:
            self._timing[0].close()
        if self._tb is not None:
            self._tb.close()


def _open_csv(path: Path, fields: tuple[str, ...]) -> tuple[TextIO, Any]:
    """A CSV file opened for appending, with its header when it is new."""
    new = not path.exists()
    file = path.open("a", newline="")
    writer = csv.writer(file)
    if new:
        writer.writerow(fields)
    return file, writer


def read_metric(csv_path: Path, key: str) -> tuple[list[int], list[float]]:
    """Returns (env_steps, values) of one key from a metrics CSV."""
    steps, values = [], []
    with Path(csv_path).open() as f:
        for row in csv.DictReader(f):
            if row["key"] == key:
                steps.append(int(row["env_steps"]))
                values.append(float(row["value"]))
    return steps, values


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

    steps, mean = read_metric(csv_path, "eval/return_mean")
    _, std = read_metric(csv_path, "eval/return_std")
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(steps, mean, label="evaluation return", color="tab:blue")
    if std:
        low = [m - s for m, s in zip(mean, std, strict=True)]
        high = [m + s for m, s in zip(mean, std, strict=True)]
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
