"""Run metrics: namespaced scalars to TensorBoard and a long-format CSV; the learning curve."""

from __future__ import annotations

import csv
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Optional


class MetricsLogger:
    """Appends `wall_s, env_steps, updates, key, value` rows; mirrors them to TensorBoard."""

    FIELDS = ("wall_s", "env_steps", "updates", "key", "value")

    def __init__(self, run_dir: Path, *, tensorboard: bool = True) -> None:
        run_dir.mkdir(parents=True, exist_ok=True)
        self.csv_path = run_dir / "metrics.csv"
        new = not self.csv_path.exists()
        self._file = self.csv_path.open("a", newline="")
        self._csv = csv.writer(self._file)
        if new:
            self._csv.writerow(self.FIELDS)
        self._start = time.monotonic()
        self._tb = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(str(run_dir / "tensorboard"))

    def log(self, scalars: Mapping[str, float], *, env_steps: int, updates: int) -> None:
        wall = round(time.monotonic() - self._start, 3)
        for key, value in scalars.items():
            self._csv.writerow((wall, env_steps, updates, key, f"{float(value):.6g}"))
            if self._tb is not None:
                self._tb.add_scalar(key, float(value), env_steps)
        self._file.flush()  # so a running job can be followed (tail, plots)

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


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
