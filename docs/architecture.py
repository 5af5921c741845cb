"""Draw docs/architecture.png, graft's floors and the imports between them, from the real imports.

    .venv/bin/python docs/architecture.py    # writes docs/architecture.png, prints the figures

The floors are the layers of the import contract in pyproject.toml ([tool.importlinter],
the first contract); every arrow is counted from the imports grimp finds in the source (the
graph `lint-imports` checks), so an import running back up, or a circle, shows in the picture
(in red) and in the printed figures.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from pathlib import Path

import grimp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.patches import FancyBboxPatch  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("graft", "learner", "actors", "minecraft", "service")

# The floors, top to bottom, as in the first [tool.importlinter] contract; each box is a
# module prefix, and a module belongs to the longest prefix it starts with.
FLOORS: tuple[tuple[str, ...], ...] = (
    ("graft",),
    ("learner",),
    ("actors", "minecraft"),
    ("service.replay", "service.weights", "service.metrics", "service.forkserver"),
    ("service.core", "service"),
)
WHAT = {
    "graft": "CLI, Python API, orchestration,\npresets, recipes, experiments, tuning",
    "learner": "the learner loop, checkpoints;\ntd3, backbone, pretrain, dqn, options",
    "actors": "env actor, evaluator,\nbehaviour policies, trees",
    "minecraft": "sim/ (world server), malmo/ (client),\nagent/ (diamond tree, A*, travel)",
    "service.replay": "replay client, codec,\nsharding; server/",
    "service.weights": "weight broadcast\n(fan-out relays)",
    "service.metrics": "CSV, TensorBoard,\npolicy lag",
    "service.forkserver": "forks replay and\nworld servers",
    "service.core": "the contracts:\ntyping.Protocols",
    "service": "__init__: the\nversion number",
}


def box_of(module: str) -> str:
    """The box (module prefix) a module belongs to: the longest prefix it starts with."""
    boxes = [b for floor in FLOORS for b in floor]
    owners = [b for b in boxes if module == b or module.startswith(b + ".")]
    return max(owners, key=len)


def floor_of(box: str) -> int:
    """The floor of a box, 0 at the top."""
    return next(i for i, floor in enumerate(FLOORS) if box in floor)


def measure() -> tuple[
    dict[tuple[str, str], int], dict[str, tuple[int, int]], set[tuple[str, str]]
]:
    """Imports between boxes (module pairs, importer -> imported), each box's size (modules,
    lines) and every import between two modules."""
    graph = grimp.build_graph(*PACKAGES, include_external_packages=False)
    arrows: dict[tuple[str, str], int] = {}
    sizes: dict[str, tuple[int, int]] = {}
    imports: set[tuple[str, str]] = set()
    for module in sorted(graph.modules):
        box = box_of(module)
        for imported in graph.find_modules_directly_imported_by(module):
            imports.add((module, imported))
            target = box_of(imported)
            if target != box:
                arrows[(box, target)] = arrows.get((box, target), 0) + 1
        modules, lines = sizes.get(box, (0, 0))
        sizes[box] = (modules + 1, lines + _lines(module))
    return arrows, sizes, imports


def _lines(module: str) -> int:
    path = ROOT.joinpath(*module.split("."))
    source = path / "__init__.py" if path.is_dir() else path.with_suffix(".py")
    return len(source.read_text().splitlines()) if source.exists() else 0


def circles(edges: Iterable[tuple[str, str]]) -> list[tuple[str, ...]]:
    """The groups of nodes that reach each other through the edges (Kosaraju), each a circle."""
    forward: dict[str, list[str]] = {}
    backward: dict[str, list[str]] = {}
    for src, dst in edges:
        forward.setdefault(src, []).append(dst)
        backward.setdefault(dst, []).append(src)
        forward.setdefault(dst, [])
        backward.setdefault(src, [])
    order: list[str] = []
    seen: set[str] = set()
    for start in sorted(forward):
        if start in seen:
            continue
        seen.add(start)
        stack = [(start, iter(forward[start]))]
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                order.append(node)
                stack.pop()
            elif child not in seen:
                seen.add(child)
                stack.append((child, iter(forward[child])))
    groups, assigned = [], set()
    for node in reversed(order):
        if node in assigned:
            continue
        group, todo = [], [node]
        assigned.add(node)
        while todo:
            current = todo.pop()
            group.append(current)
            for parent in backward[current]:
                if parent not in assigned:
                    assigned.add(parent)
                    todo.append(parent)
        if len(group) > 1:
            groups.append(tuple(sorted(group)))
    return sorted(groups)


WIDTH, HEIGHT, GAP_Y, BAND = 2.7, 1.0, 2.5, 0.7  # a box, the distance between floors, a band


def _boxes(ax: Axes, sizes: dict[str, tuple[int, int]]) -> dict[str, tuple[float, float]]:
    """The floors as grey bands and a box per module prefix; returns each box's centre."""
    centres = {
        box: (14.0 * (j + 0.5) / len(floor), -i * GAP_Y)
        for i, floor in enumerate(FLOORS)
        for j, box in enumerate(floor)
    }
    for i in range(len(FLOORS)):
        y = -i * GAP_Y
        band = FancyBboxPatch((0.0, y - BAND), 14.0, 2 * BAND, boxstyle="round,pad=0.02")
        band.set(fc="#f1f1f1", ec="none")
        ax.add_patch(band)
        ax.text(
            13.8, y, f"floor {len(FLOORS) - i}", fontsize=7, color="#666", rotation=90, va="center"
        )
    for box, (x, y) in centres.items():
        patch = FancyBboxPatch(
            (x - WIDTH / 2, y - HEIGHT / 2), WIDTH, HEIGHT, boxstyle="round,pad=0.04"
        )
        patch.set(fc="white", ec="#335", zorder=3)
        ax.add_patch(patch)
        ax.text(x, y + 0.26, box, ha="center", va="center", fontsize=10, weight="bold", zorder=4)
        ax.text(x, y - 0.12, WHAT[box], ha="center", va="center", fontsize=7.2, zorder=4)
        modules, lines = sizes.get(box, (0, 0))
        label = f"{modules} module{'s' if modules != 1 else ''}, {lines:,} lines"
        ax.text(x + WIDTH / 2, y - HEIGHT / 2 - 0.2, label, ha="right", fontsize=6.5, zorder=4)
    return centres


def _arrows(
    ax: Axes, arrows: dict[tuple[str, str], int], centres: dict[str, tuple[float, float]]
) -> dict[str, int]:
    """An arrow per importing pair, its width by its count; returns the lanes used per side.

    An arrow to the next floor goes straight down; one that skips floors runs in a lane of
    its own beside the bands, so that no arrow passes behind a box. An arrow running up or
    sideways is red.
    """
    outs = {
        b: sorted((d for (s, d) in arrows if s == b), key=lambda d: centres[d][0]) for b in centres
    }
    ins = {
        b: sorted((s for (s, d) in arrows if d == b), key=lambda s: centres[s][0]) for b in centres
    }
    lanes = {"left": 0, "right": 0}
    order = sorted(arrows.items(), key=lambda kv: (floor_of(kv[0][0]), centres[kv[0][1]][0]))
    for (src, dst), count in order:
        (x0, y0), (x1, y1) = centres[src], centres[dst]
        # Where the arrow leaves its source and enters its target: spread along the edges.
        sx = x0 - WIDTH / 2 + WIDTH * (outs[src].index(dst) + 1) / (len(outs[src]) + 1)
        dx = x1 - WIDTH / 2 + WIDTH * (ins[dst].index(src) + 1) / (len(ins[dst]) + 1)
        up = floor_of(dst) <= floor_of(src)
        colour, lw = ("#c00" if up else "#4a6fa5"), 0.7 + min(count, 40) / 12
        top = y1 + HEIGHT / 2
        path = [(sx, y0 - HEIGHT / 2), (dx, top)]
        if not up and floor_of(dst) - floor_of(src) > 1:
            side = "left" if x1 < 7.0 else "right"
            lanes[side] += 1
            lane = -0.25 * lanes[side] if side == "left" else 14.0 + 0.25 * lanes[side]
            below = y0 - BAND - 0.15 - 0.06 * lanes[side]
            above = y1 + BAND + 0.15 + 0.06 * lanes[side]
            path[1:1] = [(sx, below), (lane, below), (lane, above), (dx, above)]
        xs, ys = zip(*path, strict=True)
        ax.plot(xs[:-1], ys[:-1], color=colour, lw=lw, alpha=0.8, zorder=2)
        head = {"arrowstyle": "-|>", "lw": lw, "color": colour, "alpha": 0.8, "shrinkA": 0}
        ax.annotate("", xy=path[-1], xytext=path[-2], zorder=2, arrowprops={**head, "shrinkB": 1})
        ax.text(dx + 0.06, top + 0.12, str(count), fontsize=7, color=colour, zorder=5)
    return lanes


def draw(
    arrows: dict[tuple[str, str], int],
    sizes: dict[str, tuple[int, int]],
    module_circles: int,
    out: Path,
) -> None:
    """The picture: floors as bands, top to bottom, and the arrows between their boxes."""
    fig, ax = plt.subplots(figsize=(14, 10))
    lanes = _arrows(ax, arrows, _boxes(ax, sizes))
    ax.set_xlim(-0.3 - 0.25 * lanes["left"], 14.3 + 0.25 * lanes["right"])
    ax.set_ylim(-(len(FLOORS) - 1) * GAP_Y - 1.1, 1.0)
    ax.set_aspect("equal")
    ax.axis("off")
    up = sum(1 for (s, d) in arrows if floor_of(d) <= floor_of(s))
    ax.set_title(
        "graft's floors, drawn from its imports (docs/architecture.py): "
        f"{len(arrows)} arrows, each labelled with the module imports it carries;\n"
        f"{up} running up or sideways, {len(circles(arrows))} circles between boxes, "
        f"{module_circles} between modules",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "architecture.png")
    args = parser.parse_args()
    arrows, sizes, imports = measure()
    module_circles = circles(imports)
    up = [(s, d) for (s, d) in arrows if floor_of(d) <= floor_of(s)]
    boxes = sum(len(f) for f in FLOORS)
    print(
        f"floors: {len(FLOORS)}, boxes: {boxes}, arrows: {len(arrows)}, up or sideways: {len(up)}"
    )
    print(f"circles between boxes: {circles(arrows) or 'none'}")
    print(f"circles between modules: {module_circles or 'none'}")
    for (src, dst), count in sorted(arrows.items(), key=lambda kv: (floor_of(kv[0][0]), kv[0])):
        mark = "  (UP)" if (src, dst) in up else ""
        print(f"  {src:20s} -> {dst:20s} {count:4d} module imports{mark}")
    draw(arrows, sizes, len(module_circles), args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
