"""What a benchmark that runs two arms in turn, round after round, reports: each arm's
median CPU and wall seconds over the rounds, as a table, and the second arm's against the
first's."""

from __future__ import annotations

import statistics


def report(
    figures: dict[str, list[tuple[float, float]]], *, column: str, unit: str, digits: int
) -> None:
    """Prints ``| column | CPU | wall |`` with each arm's medians (``digits`` decimals,
    ``unit`` after CPU and wall, e.g. " a run"), then ``second / first: CPU r, wall r``."""
    print(f"| {column} | CPU{unit}, median | wall{unit}, median |")
    print("|---|---|---|")
    medians = {}
    for arm, values in figures.items():
        medians[arm] = [statistics.median(v[i] for v in values) for i in (0, 1)]
        print(f"| {arm} | {medians[arm][0]:.{digits}f} s | {medians[arm][1]:.{digits}f} s |")
    (first, base), (second, new) = medians.items()
    print(f"\n{second} / {first}: CPU {new[0] / base[0]:.2f}, wall {new[1] / base[1]:.2f}")
