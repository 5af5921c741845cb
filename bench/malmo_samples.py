"""Malmo's 17 MalmoEnv sample missions in the simulator: how long each world takes to
build (its terrain, drawing and generators), side by side, as a ratio to the plain
``defaultflatworld.xml``; and, with ``--png``, plans of the worlds the maze, classroom
and build battle generators made (one horizontal slice a panel: the maze's path level,
each classroom floor's lowest air layer, the build battle's structure level).

    python bench/malmo_samples.py [--repeats 3] [--seed 5] [--png docs/img/malmo-generators.png]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from minecraft import blocks as B
from minecraft.malmo.mission import parse_mission
from minecraft.malmo.roles import role_mission
from minecraft.sim.world import World

SAMPLES = (
    Path(__file__).parents[1] / "tests" / "minecraft" / "compat" / "missions"
    / "malmo_samples"
)  # fmt: skip


def build(name: str, seed: int) -> tuple[World, float]:
    """Role 0's world for a sample, and the seconds it took."""
    mission = parse_mission(role_mission((SAMPLES / name).read_text(), 0).xml)
    t0 = time.perf_counter()
    world = World(mission, seed)
    return world, time.perf_counter() - t0


def _panels(seed: int) -> list[tuple[str, World, int, tuple[int, int, int, int]]]:
    """(title, world, y, (x0, x1, z0, z1)) for each slice to draw."""
    out = []
    w, _ = build("mazerunner.xml", seed)
    out.append(("mazerunner: maze, y=226", w, 226, (0, 57, 0, 57)))
    for name in ("findthegoal.xml", "obstacles.xml", "attic.xml", "vertical.xml"):
        spec = parse_mission((SAMPLES / name).read_text()).classroom
        assert spec is not None
        w, _ = build(name, seed)
        x1, h, z1 = spec.size
        for y in range(55, 55 + h - 3, 6):
            if any(w.get(x, y - 1, z) != B.AIR for x in range(x1) for z in range(z1)):
                out.append((f"{name[:-4]}: floor y={y}", w, y, (-2, x1 + 2, -2, z1 + 2)))
    w, _ = build("buildbattle.xml", seed)
    out.append(("buildbattle: y=5 (goal x0-1, copy x4-5)", w, 5, (-3, 9, -3, 5)))
    return out


def plans(path: Path, seed: int) -> None:
    """Write the generated worlds' plans to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = _panels(seed)
    cols = 4
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 4 * rows))
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (title, w, y, (x0, x1, z0, z1)) in zip(axes.ravel(), panels, strict=False):
        img = np.zeros((z1 - z0, x1 - x0, 3))
        for x in range(x0, x1):
            for z in range(z0, z1):
                bid = w.get(x, y, z)
                if bid == B.AIR:  # show what is underfoot, darker
                    under = w.get(x, y - 1, z)
                    img[z - z0, x - x0] = np.array(B.BLOCKS[under].colour) / 255 * 0.45
                else:
                    img[z - z0, x - x0] = np.array(B.BLOCKS[bid].colour) / 255
        ax.imshow(img, origin="upper", extent=(x0, x1, z1, z0), interpolation="nearest")
        b = w.player.body
        if abs(b.y - y) < 3:
            ax.plot([b.x], [b.z], "w*", markersize=12, markeredgecolor="k")
        ax.set_title(title, fontsize=9)
        ax.axis("on")
        ax.set_xlabel("x (east)", fontsize=7)
        ax.set_ylabel("z (south)", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.suptitle(
        f"Malmo's generated sample worlds in the simulator (world seed {seed}); star: the "
        "agent's start; bright: blocks at the slice, dark: the floor under air",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--png", type=Path, default=None)
    a = ap.parse_args()
    names = sorted(p.name for p in SAMPLES.glob("*.xml"))
    times: dict[str, list[float]] = {n: [] for n in names}
    for _ in range(a.repeats):  # interleaved, so that load on the machine hits all alike
        for n in names:
            times[n].append(build(n, a.seed)[1])
    base = statistics.median(times["defaultflatworld.xml"])
    print(f"{'mission':28s} {'median s':>9s} {'x flat':>7s}")
    for n in names:
        med = statistics.median(times[n])
        print(f"{n:28s} {med:9.3f} {med / base:7.1f}")
    if a.png is not None:
        plans(a.png, a.seed)
        print(f"wrote {a.png}")


if __name__ == "__main__":
    main()
