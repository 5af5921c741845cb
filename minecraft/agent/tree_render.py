"""Print a py_trees tree as ASCII and draw it as a PNG.

py_trees renders PNGs through graphviz ``dot``; when ``dot`` is not installed (our
machines) the tree is laid out here (leaves left to right, parents centred over their
children) and drawn with matplotlib, with py_trees' shapes in spirit: composites as
boxes labelled with their kind, conditions (names ending in ``?``) as ellipses.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import py_trees
from py_trees.behaviour import Behaviour

_KIND = {
    py_trees.composites.Selector: ("?", "#fde9b8"),
    py_trees.composites.Sequence: ("→", "#cfe3fb"),
    py_trees.composites.Parallel: ("⇉", "#e4d4f4"),
}


def ascii_tree(root: Behaviour) -> str:
    """py_trees' ASCII rendering of the tree."""
    return py_trees.display.ascii_tree(root)


def _children(node: Behaviour, collapse: tuple[str, ...]) -> list[Behaviour]:
    return [] if node.name in collapse else list(node.children)


def _layout(root: Behaviour, collapse: tuple[str, ...]) -> dict[int, tuple[float, int]]:
    pos: dict[int, tuple[float, int]] = {}
    next_x = [0.0]

    def place(node: Behaviour, depth: int) -> float:
        kids = _children(node, collapse)
        if not kids:
            x = next_x[0]
            next_x[0] += 1.0
        else:
            xs = [place(k, depth + 1) for k in kids]
            x = (xs[0] + xs[-1]) / 2.0
        pos[id(node)] = (x, depth)
        return x

    place(root, 0)
    return pos


def render_png(root: Behaviour, path: Path, *, collapse: tuple[str, ...] = ("Travel",)) -> Path:
    """Write the tree as a PNG; with graphviz through py_trees, else with matplotlib.

    Args:
        root: the tree.
        path: the PNG to write.
        collapse: (matplotlib drawing) names of composites drawn as one node with their
            children hidden; by default the A* travel sub-tree, which appears under every
            travelling branch (the ASCII print shows it in full).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if shutil.which("dot") is not None:
        try:
            py_trees.display.render_dot_tree(
                root,
                target_directory=str(path.parent),
                name=path.stem,
                with_blackboard_variables=False,
            )
            return path
        except Exception:  # pydot missing or dot failed: fall back to matplotlib
            pass
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pos = _layout(root, collapse)
    width = max(x for x, _ in pos.values()) + 1
    depth = max(d for _, d in pos.values()) + 1
    fig, ax = plt.subplots(figsize=(max(8.0, width * 0.9), max(4.0, depth * 1.0)))
    nodes = [n for n in root.iterate() if id(n) in pos]
    for node in nodes:
        x, d = pos[id(node)]
        for kid in _children(node, collapse):
            kx, kd = pos[id(kid)]
            ax.plot([x, kx], [-d, -kd], color="#888888", linewidth=0.6, zorder=1)
    for node in nodes:
        x, d = pos[id(node)]
        kind = next((v for k, v in _KIND.items() if isinstance(node, k)), None)
        if node.name in collapse:
            label, colour, style = f"{node.name} (A*) [+]", "#fbd3d3", "round,pad=0.25"
        elif kind is not None:
            label, colour, style = f"{kind[0]} {node.name}", kind[1], "round,pad=0.25"
        elif node.name.endswith("?"):
            label, colour, style = node.name, "#e2f5d9", "ellipse,pad=0.2"
        else:
            label, colour, style = node.name, "#f4f4f4", "square,pad=0.25"
        ax.text(x, -d, label.replace(" ", "\n", 2) if len(label) > 14 else label,
                ha="center", va="center", fontsize=6, zorder=2,
                bbox={"boxstyle": style, "facecolor": colour, "edgecolor": "#555555",
                      "linewidth": 0.5})  # fmt: skip
    ax.set_xlim(-1, width)
    ax.set_ylim(-depth + 0.4, 0.6)
    ax.axis("off")
    total = sum(1 for _ in root.iterate())
    ax.set_title(f"{root.name}: {total} nodes ({', '.join(collapse)} collapsed)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
