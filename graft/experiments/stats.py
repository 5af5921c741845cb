"""Honest per-seed statistics: the mean and the interquartile mean (IQM), each with a 95 %
percentile-bootstrap confidence interval over seeds, as rliable reports them (Agarwal et
al., 2021, "Deep RL at the Edge of the Statistical Precipice").

    summary = summarize([-132.8, -136.9, -135.9, -135.2, -134.8])
    print(summary.line())  # mean -135.1 [-136.2, -134.0], IQM -135.3 [...], 5 seeds

Few seeds give intervals that are too narrow (the bootstrap cannot see beyond the values
it was given): below `MIN_SEEDS` there is no interval, and `line()` lists the values
instead. The resampling generator is seeded, so the same values print the same interval.

    python -m graft.experiments.stats -- -132.8 -136.9 -135.9 -135.2 -134.8
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

RESAMPLES = 10_000
CONFIDENCE = 0.95
MIN_SEEDS = 3
"""Fewest values given an interval: from two, the bootstrap's 95 % interval is only
their range."""


def iqm(values: Sequence[float] | np.ndarray) -> float:
    """Interquartile mean: the mean of the middle half (the lowest and highest
    ⌊n/4⌋ values cut, as scipy's ``trim_mean(x, 0.25)``; the plain mean for n < 4)."""
    x = np.sort(np.asarray(values, dtype=np.float64))
    cut = int(0.25 * len(x))
    return float(x[cut : len(x) - cut].mean())


def bootstrap_ci(
    values: Sequence[float] | np.ndarray,
    statistic: Callable[[np.ndarray], float],
    *,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile-bootstrap interval of `statistic` over `values` (NaN, NaN for fewer
    than `MIN_SEEDS` values).

    Raises:
        ValueError: no values, or a confidence outside (0, 1).
    """
    x = np.asarray(values, dtype=np.float64)
    if len(x) == 0:
        raise ValueError("bootstrap_ci needs at least one value")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence={confidence} must lie in (0, 1)")
    if len(x) < MIN_SEEDS:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    samples = x[rng.integers(0, len(x), size=(resamples, len(x)))]
    stats = np.apply_along_axis(statistic, 1, samples)
    tail = (1 - confidence) / 2
    low, high = np.quantile(stats, [tail, 1 - tail])
    return float(low), float(high)


@dataclass(frozen=True)
class Summary:
    """Mean and IQM of per-seed values, each with its bootstrap interval."""

    values: tuple[float, ...]
    mean: float
    mean_ci: tuple[float, float]
    iqm: float
    iqm_ci: tuple[float, float]

    @property
    def n(self) -> int:
        return len(self.values)

    def line(self, digits: int = 1) -> str:
        """``mean -135.1 [-136.2, -133.8], IQM -135.3 [-136.6, -133.5], 5 seeds (95 %
        bootstrap CI)``; below `MIN_SEEDS`, ``mean -136.5 (2 seeds: -137.0, -136.0; no
        interval)``."""
        if self.n < MIN_SEEDS:
            listed = ", ".join(f"{v:.{digits}f}" for v in self.values)
            seeds = "1 seed," if self.n == 1 else f"{self.n} seeds: {listed};"
            return f"mean {self.mean:.{digits}f} ({seeds} no interval)"

        def interval(value: float, ci: tuple[float, float]) -> str:
            return f"{value:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"

        return (
            f"mean {interval(self.mean, self.mean_ci)}, IQM {interval(self.iqm, self.iqm_ci)}, "
            f"{self.n} seeds (95 % bootstrap CI)"
        )


def summarize(values: Sequence[float] | np.ndarray, *, seed: int = 0) -> Summary:
    """The mean and IQM of per-seed values, with 95 % bootstrap intervals.

    Raises:
        ValueError: no values, or a value that is not finite.
    """
    x = np.asarray(values, dtype=np.float64)
    if len(x) == 0 or not np.all(np.isfinite(x)):
        raise ValueError(f"summarize needs finite per-seed values, got {list(values)}")
    return Summary(
        values=tuple(float(v) for v in x),
        mean=float(x.mean()),
        mean_ci=bootstrap_ci(x, np.mean, seed=seed),
        iqm=iqm(x),
        iqm_ci=bootstrap_ci(x, iqm, seed=seed),
    )


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description="mean and IQM of per-seed values with 95 % bootstrap intervals"
    )
    parser.add_argument("values", type=float, nargs="+", help="one value per seed")
    parser.add_argument("--digits", type=int, default=1)
    args = parser.parse_args(argv)
    print(summarize(args.values).line(args.digits))


if __name__ == "__main__":
    main()
