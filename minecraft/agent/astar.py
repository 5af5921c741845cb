"""A* travel planner on the augmented space (agent position, blocks destroyed so far), from
the 15×15×15 grid observation (paper sec. III-D, Fig. 1).

Actions and costs, as in the paper:

* ``move_to`` an adjacent block: 1 when the way is free (walking, or dropping up to 3
  blocks, a drop Minecraft does not hurt), 2 when an obstacle one block high must be
  jumped, impossible otherwise (no pillaring up, no swimming, no lava, no fall > 3).
* ``destroy`` a neighbouring block: 5. Only blocks that stand in the way of one of the
  moves from the current position are candidates, in a fixed top-down order per move
  (breaking the head block before the feet block is the order a player digs in), and
  never a block touching water or lava (the liquid would flow in) nor the block under
  the agent when the fall would be longer than 3 or end in a liquid (no digging into a
  cave or a lava lake).

A search node stores only what changed from its parent (a position, or one destroyed
block) plus a pointer to the parent; the destroyed set of a node is recovered by walking
its chain of destroy ancestors (each node also points at its nearest one, so the walk
touches destroyed blocks only). Nodes are told apart by (position, a Zobrist hash of the
destroyed set), which is independent of the order the blocks were destroyed in.

The heuristic is admissible: every move changes the horizontal Manhattan distance by at
most 1 and costs at least 1; a rise of one block needs a jump (cost 2, which also moves 1
sideways); a move descends at most 3 blocks. Destroy costs are not counted, but for the
goal's own two cells: standing there needs their solid blocks broken, 5 each.

The search itself is compiled (``astar_kernel``, numba; why, and by how much, there).

Coordinates are grid indices ``(x, y, z)``; the grid array is indexed ``[y, z, x]`` (Malmo's
order: x fastest, then z, then y). The caller re-plans every tick; ``Planner`` memoises
the answer for an unchanged (grid, start, goals) so a tick that changed nothing costs a
dictionary lookup.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from minecraft import blocks as B
from minecraft.agent import astar_kernel
from minecraft.agent.astar_kernel import (  # noqa: F401 (this module's API)
    DESTROY_COST,
    FREE,
    HARD,
    HORIZONTAL,
    JUMP_COST,
    LAVA,
    MAX_DROP,
    MOVE_COST,
    SOLID,
    WATER,
)
from minecraft.compiled import compile_once

Cell = tuple[int, int, int]

NEIGHBOURS6: tuple[Cell, ...] = (
    (1, 0, 0),
    (-1, 0, 0),
    (0, 1, 0),
    (0, -1, 0),
    (0, 0, 1),
    (0, 0, -1),
)

# Block id -> category. Torches, air: free. Bedrock and obsidian (needs diamond tools):
# hard. Leaves and glass are solid and breakable.
_CATEGORY = np.full(len(B.BLOCKS), SOLID, dtype=np.uint8)
_CATEGORY[[b for b in range(len(B.BLOCKS)) if not B.SOLID[b] and not B.LIQUID[b]]] = FREE
_CATEGORY[B.IS_WATER] = WATER
_CATEGORY[B.IS_LAVA] = LAVA
_CATEGORY[[B.BEDROCK, B.ID["obsidian"]]] = HARD
_NAME_CATEGORY = {b.name: int(_CATEGORY[i]) for i, b in enumerate(B.BLOCKS)}


def categorise(names: Iterable[str], shape: tuple[int, int, int] = (15, 15, 15)) -> np.ndarray:
    """Planning categories from grid block names (Malmo order); unknown names are solid."""
    flat = np.fromiter((_NAME_CATEGORY.get(n, SOLID) for n in names), dtype=np.uint8)
    return flat.reshape(shape)


def categories_of_ids(ids: np.ndarray) -> np.ndarray:
    """Planning categories from an array of block ids (any shape)."""
    return _CATEGORY[ids]


@dataclass(frozen=True)
class Step:
    """One planned action.

    Attributes:
        kind: ``"move"`` (walk, jump or drop to ``cell``) or ``"destroy"`` (break ``cell``).
        cell: the destination feet cell, or the block to break.
    """

    kind: str
    cell: Cell


@dataclass(frozen=True)
class Plan:
    """A* result.

    Attributes:
        steps: actions from the start, in order (empty when already at a goal).
        cost: total cost of ``steps``.
        reached: the steps end at a goal; False means the best partial plan (towards the
            expanded node closest to a goal by the heuristic) or no plan at all.
        expanded: nodes expanded by the search.
    """

    steps: tuple[Step, ...]
    cost: float
    reached: bool
    expanded: int

    @property
    def destroyed(self) -> tuple[Cell, ...]:
        """Blocks the plan breaks, in order."""
        return tuple(s.cell for s in self.steps if s.kind == "destroy")


@functools.cache
def _zobrist(n: int) -> np.ndarray:
    """Random 63-bit keys, one per cell; a destroyed set hashes to the XOR of its keys."""
    return np.random.default_rng(0x5EED).integers(1, 2**63, size=n, dtype=np.int64)


def _breakable(grid: np.ndarray) -> np.ndarray:
    """Per cell (flat, Malmo order): 1 for a solid block no water or lava touches."""
    liquid = np.isin(grid, (WATER, LAVA))
    touched = liquid.copy()
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        touched[tuple(hi)] |= liquid[tuple(lo)]  # the cell above / after a liquid
        touched[tuple(lo)] |= liquid[tuple(hi)]  # the cell below / before one
    return ((grid == SOLID) & ~touched).astype(np.uint8).reshape(-1)


def _goal_solids(
    cells: np.ndarray, dims: tuple[int, int, int], goals: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per goal, the solid blocks in its own two cells (feet, head): their number, and
    (cell, goal) rows. Standing there needs them broken, whatever the way in."""
    nx, ny, nz = dims
    counts = np.zeros(len(goals), dtype=np.int64)
    pairs = []
    for k, (x, y, z) in enumerate(goals.tolist()):
        for cy in (y, y + 1):
            if 0 <= x < nx and 0 <= cy < ny and 0 <= z < nz:
                i = (cy * nz + z) * nx + x
                if cells[i] == SOLID:
                    counts[k] += 1
                    pairs.append((i, k))
    return counts, np.array(pairs, dtype=np.int64).reshape(-1, 2)


def warm_up() -> None:
    """Compiles the search (or loads it from numba's cache), one process at a time
    (``compiled.compile_once``), so a client's first plan does not wait for the compiler."""
    compile_once("astar", astar_kernel.search, _compile)


def _compile() -> None:
    ints = np.zeros(3, dtype=np.int64)
    cells = np.zeros(1, dtype=np.uint8)
    none = np.zeros((0, 3), dtype=np.int64)
    astar_kernel.search(ints, cells, cells, ints, ints, none, ints, none[:, :2].copy(), 0, 0)


def _cell(i: int, nx: int, nz: int) -> Cell:
    """Cell (x, y, z) of a flat index."""
    yz, x = divmod(i, nx)
    y, z = divmod(yz, nz)
    return (x, y, z)


def plan(
    grid: np.ndarray,
    start: Cell,
    goals: Iterable[Cell],
    *,
    max_expansions: int = 20_000,
    sets_per_position: int = 4,
) -> Plan:
    """Plan from ``start`` to any cell of ``goals`` on a category grid ``[y, z, x]``.

    Args:
        grid: planning categories (FREE, SOLID, HARD, WATER, LAVA), indexed [y, z, x].
        start: the agent's feet cell (x, y, z).
        goals: acceptable feet cells.
        max_expansions: search budget; when exhausted, the best partial plan is returned
            (``reached`` False).
        sets_per_position: at most this many nodes (with different destroyed sets) are
            expanded at one position, the cheapest first. The augmented space grows
            exponentially with the blocks in reach; this bound keeps a search in solid rock to a few
            thousand nodes and only matters for paths that come back to a position
            with a different set of broken blocks.
    """
    end, reached, expanded, parent, pos, broken, g = _search(
        grid, start, goals, max_expansions, sets_per_position
    )
    nx, nz = grid.shape[2], grid.shape[1]
    steps: list[Step] = []
    n = int(end)
    while parent[n] != -1:
        if broken[n] != -1:
            steps.append(Step("destroy", _cell(int(broken[n]), nx, nz)))
        else:
            steps.append(Step("move", _cell(int(pos[n]), nx, nz)))
        n = int(parent[n])
    return Plan(tuple(reversed(steps)), float(g[end]), bool(reached), int(expanded))


def _search(
    grid: np.ndarray,
    start: Cell,
    goals: Iterable[Cell],
    max_expansions: int,
    sets_per_position: int,
) -> tuple:
    """The compiled search's answer (``astar_kernel.search``) for these arguments."""
    if grid.ndim != 3:
        raise ValueError(f"grid must be 3-D [y, z, x], got shape {grid.shape}")
    ny, nz, nx = grid.shape
    cells = np.ascontiguousarray(grid, dtype=np.uint8).reshape(-1)
    goal_cells = np.array(sorted(set(goals)), dtype=np.int64).reshape(-1, 3)
    counts, pairs = _goal_solids(cells, (nx, ny, nz), goal_cells)
    warm_up()
    return astar_kernel.search(
        np.array([nx, ny, nz], dtype=np.int64), cells, _breakable(grid), _zobrist(cells.size),
        np.array(start, dtype=np.int64), goal_cells, counts, pairs, max_expansions,
        sets_per_position,
    )  # fmt: skip


class Planner:
    """Re-plans on every call; identical inputs return the memoised plan.

    Args:
        max_expansions: per-search budget.
        cache_size: plans remembered.
    """

    def __init__(self, *, max_expansions: int = 4_000, cache_size: int = 64) -> None:
        self.max_expansions = max_expansions
        self.cache_size = cache_size
        self._cache: dict[tuple[bytes, Cell, frozenset[Cell]], Plan] = {}
        self.searches = 0

    def __call__(self, grid: np.ndarray, start: Cell, goals: Iterable[Cell]) -> Plan:
        """The plan for this grid, start and goal set."""
        g = frozenset(goals)
        key = (np.ascontiguousarray(grid, dtype=np.uint8).tobytes(), start, g)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        self.searches += 1
        result = plan(grid, start, g, max_expansions=self.max_expansions)
        if len(self._cache) >= self.cache_size:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = result
        return result
