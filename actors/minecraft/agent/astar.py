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
sideways); a move descends at most 3 blocks. Destroy costs are not counted.

Coordinates are grid indices ``(x, y, z)``; the grid array is indexed ``[y, z, x]`` (Malmo's
order: x fastest, then z, then y). The caller re-plans every tick; ``Planner`` memoises
the answer for an unchanged (grid, start, goals) so a tick that changed nothing costs a
dictionary lookup.
"""

from __future__ import annotations

import functools
import heapq
import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Optional

import numpy as np

from actors.minecraft import blocks as B

Cell = tuple[int, int, int]

# Cell categories of the planning grid.
FREE, SOLID, HARD, WATER, LAVA = 0, 1, 2, 3, 4
MOVE_COST = 1.0
JUMP_COST = 2.0
DESTROY_COST = 5.0
MAX_DROP = 3  # blocks; Minecraft's fall damage is ceil(d - 3)
HORIZONTAL: tuple[tuple[int, int], ...] = ((1, 0), (-1, 0), (0, 1), (0, -1))
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


class _Node:
    """A search node: the single changed element and links to the parent."""

    __slots__ = ("parent", "pos", "broken", "g", "zkey", "last_destroy")

    def __init__(
        self,
        parent: Optional[_Node],
        pos: Cell,
        broken: Optional[int],
        g: float,
        zkey: int,
    ) -> None:
        self.parent = parent
        self.pos = pos
        self.broken = broken  # flat index of the block destroyed to reach this node
        self.g = g
        self.zkey = zkey
        if broken is not None:
            self.last_destroy: Optional[_Node] = self
        else:
            self.last_destroy = parent.last_destroy if parent is not None else None

    def destroyed_cells(self) -> list[int]:
        """Flat indices of the blocks destroyed on the way to this node."""
        out = []
        n = self.last_destroy
        while n is not None:
            assert n.broken is not None
            out.append(n.broken)
            p = n.parent
            n = p.last_destroy if p is not None else None
        return out

    def destroyed(self, flat_index: int) -> bool:
        """Whether the block at ``flat_index`` was destroyed on the way to this node."""
        n = self.last_destroy
        while n is not None:
            if n.broken == flat_index:
                return True
            p = n.parent
            n = p.last_destroy if p is not None else None
        return False


def heuristic(pos: Cell, goal: Cell) -> float:
    """Admissible cost-to-go from ``pos`` to ``goal`` (destroys not counted)."""
    hd = abs(goal[0] - pos[0]) + abs(goal[2] - pos[2])
    dy = goal[1] - pos[1]
    if dy > 0:
        return JUMP_COST * dy + max(0, hd - dy) * MOVE_COST
    return max(hd, math.ceil(-dy / MAX_DROP)) * MOVE_COST


@functools.cache
def _zobrist(n: int) -> list[int]:
    """Random 63-bit keys, one per cell; a destroyed set hashes to the XOR of its keys."""
    return np.random.default_rng(0x5EED).integers(1, 2**63, size=n, dtype=np.int64).tolist()


def _breakable(grid: np.ndarray) -> bytes:
    """Per cell (flat, Malmo order): 1 for a solid block no water or lava touches."""
    liquid = np.isin(grid, (WATER, LAVA))
    touched = liquid.copy()
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(None, -1), slice(1, None)
        touched[tuple(hi)] |= liquid[tuple(lo)]  # the cell above / after a liquid
        touched[tuple(lo)] |= liquid[tuple(hi)]  # the cell below / before one
    return ((grid == SOLID) & ~touched).astype(np.uint8).reshape(-1).tobytes()


class _Search:
    """One A* search over a fixed grid."""

    def __init__(self, grid: np.ndarray, goals: frozenset[Cell], sets_per_position: int) -> None:
        self.sets_per_position = sets_per_position
        if grid.ndim != 3:
            raise ValueError(f"grid must be 3-D [y, z, x], got shape {grid.shape}")
        self.ny, self.nz, self.nx = grid.shape
        self.cells = bytes(np.ascontiguousarray(grid, dtype=np.uint8).reshape(-1))
        self._breakable = _breakable(grid)
        self.goals = goals
        self.zobrist = _zobrist(len(self.cells))
        # h's parts: each goal with its solid own cells, and solid cell -> goals it blocks.
        self._goal_terms: list[tuple[Cell, int]] = []
        self._goal_solids: dict[int, list[int]] = {}
        for k, g in enumerate(goals):
            solid = [i for c in (g, (g[0], g[1] + 1, g[2])) if self._is_solid(i := self.index(c))]
            self._goal_terms.append((g, len(solid)))
            for i in solid:
                self._goal_solids.setdefault(i, []).append(k)
        self._h_at: dict[Cell, tuple[float, list[float]]] = {}

    def _is_solid(self, i: int) -> bool:
        return i >= 0 and self.cells[i] == SOLID

    # ---------------------------------------------------------------- cells
    def index(self, c: Cell) -> int:
        """Flat index of cell ``c``, or -1 outside the grid."""
        x, y, z = c
        if 0 <= x < self.nx and 0 <= y < self.ny and 0 <= z < self.nz:
            return (y * self.nz + z) * self.nx + x
        return -1

    def cat(self, c: Cell, node: _Node) -> int:
        """Category of ``c`` in the node's state (outside the grid: hard)."""
        x, y, z = c
        if not (0 <= x < self.nx and 0 <= y < self.ny and 0 <= z < self.nz):
            return HARD
        i = (y * self.nz + z) * self.nx + x
        k = self.cells[i]
        if k == SOLID and node.destroyed(i):
            return FREE
        return k

    def breakable(self, c: Cell) -> bool:
        """A solid block that may be destroyed: no liquid touches it."""
        i = self.index(c)
        return i >= 0 and self._breakable[i] == 1

    def landing(self, c: Cell, node: _Node, below_first: int = 1) -> Optional[Cell]:
        """Where a body whose feet enter free cell ``c`` comes to rest, if safely.

        Returns None for a drop longer than MAX_DROP, into a liquid, or off the grid.
        """
        x, y, z = c
        for d in range(0, MAX_DROP + 1):
            under = self.cat((x, y - d - 1, z), node)
            here = self.cat((x, y - d, z), node)
            if here != FREE:
                return None
            if under in (SOLID, HARD):
                return (x, y - d, z)
            if under != FREE:
                return None  # water or lava below
        return None

    # ------------------------------------------------------------ successors
    def blockers(self, cells: list[Cell], node: _Node) -> Optional[list[Cell]]:
        """Solid cells among ``cells`` to destroy (in order), or None if one cannot be."""
        out = []
        for c in cells:
            k = self.cat(c, node)
            if k == FREE:
                continue
            if k != SOLID or not self.breakable(c):
                return None
            out.append(c)
        return out

    def options(self, node: _Node) -> list[tuple[list[Cell], Cell, float]]:
        """Moves from ``node``: (blocks to destroy first, top first; target cell; cost of
        the move itself). The landing is resolved after the destroys."""
        x, y, z = node.pos
        out: list[tuple[list[Cell], Cell, float]] = []
        for dx, dz in HORIZONTAL:
            nx_, nz_ = x + dx, z + dz
            feet, head = (nx_, y, nz_), (nx_, y + 1, nz_)
            if self.cat(feet, node) in (SOLID, HARD):
                # Jump onto the obstacle: head room above us and two free cells above it.
                up = self.blockers([(x, y + 2, z), (nx_, y + 2, nz_), head], node)
                if up is not None:
                    out.append((up, head, JUMP_COST))
            walk = self.blockers([head, feet], node)
            if walk is not None:
                out.append((walk, feet, MOVE_COST))
        down = self.blockers([(x, y - 1, z)], node)
        if down is not None:
            out.append((down, (x, y - 1, z), MOVE_COST))
        return out

    def successors(self, node: _Node) -> list[_Node]:
        """Arrival nodes reachable from ``node``, each with its destroy nodes chained
        in between (one changed element per node)."""
        out = []
        for blocks, target, cost in self.options(node):
            n = node
            for c in blocks:
                i = self.index(c)
                n = _Node(n, n.pos, i, n.g + DESTROY_COST, n.zkey ^ self.zobrist[i])
            land = self.landing(target, n)
            if land is None:
                continue
            if cost == JUMP_COST and land != target:
                continue  # a jump must land on the obstacle
            out.append(_Node(n, land, None, n.g + cost, n.zkey))
        return out

    def cell(self, i: int) -> Cell:
        """Cell (x, y, z) of a flat index."""
        yz, x = divmod(i, self.nx)
        y, z = divmod(yz, self.nz)
        return (x, y, z)

    def unwind(self, node: _Node) -> tuple[Step, ...]:
        """The steps from the root to ``node``, following parent pointers."""
        steps: list[Step] = []
        n: Optional[_Node] = node
        while n is not None and n.parent is not None:
            if n.broken is not None:
                steps.append(Step("destroy", self.cell(n.broken)))
            else:
                steps.append(Step("move", n.pos))
            n = n.parent
        return tuple(reversed(steps))

    # ----------------------------------------------------------------- search
    def h(self, node: _Node) -> float:
        """Admissible: the move bound plus 5 per solid block in the goal's own two cells
        (standing there needs them broken, whatever the way in).

        The bound at a position with nothing destroyed is kept per position; a node's
        destroyed blocks change it only when one of them is a goal's own cell."""
        at = self._h_at.get(node.pos)
        if at is None:
            at = self._h_at[node.pos] = self._h_intact(node.pos)
        bound, per_goal = at
        if node.last_destroy is None or not self._goal_solids:
            return bound
        opened = [i for i in node.destroyed_cells() if i in self._goal_solids]
        if not opened:
            return bound
        v = list(per_goal)
        for i in opened:
            for k in self._goal_solids[i]:
                v[k] -= DESTROY_COST
        return min(v)

    def _h_intact(self, pos: Cell) -> tuple[float, list[float]]:
        """(h with nothing destroyed, each goal's term of that minimum)."""
        v = [heuristic(pos, g) + DESTROY_COST * n for g, n in self._goal_terms]
        return min(v), v

    def run(self, start: Cell, max_expansions: int) -> Plan:
        if not self.goals:
            return Plan((), 0.0, False, 0)
        counter = itertools.count()
        root = _Node(None, start, None, 0.0, 0)
        best_g: dict[tuple[Cell, int], float] = {(start, 0): 0.0}
        h0 = self.h(root)
        expansions_at: dict[Cell, int] = {}
        heap: list[tuple[float, float, int, _Node]] = [(h0, -0.0, next(counter), root)]
        best, best_h = root, h0
        expanded = 0
        while heap and expanded < max_expansions:
            _, _, _, node = heapq.heappop(heap)
            if best_g.get((node.pos, node.zkey), math.inf) < node.g:
                continue  # a stale entry
            if node.pos in self.goals:
                return Plan(self.unwind(node), node.g, True, expanded)
            seen = expansions_at.get(node.pos, 0)
            if seen >= self.sets_per_position:
                continue
            expansions_at[node.pos] = seen + 1
            expanded += 1
            hn = self.h(node)
            if hn < best_h or (hn == best_h and node.g < best.g):
                best, best_h = node, hn
            for child in self.successors(node):
                g = child.g
                key = (child.pos, child.zkey)
                if g < best_g.get(key, math.inf):
                    best_g[key] = g
                    # Ties on f go to the deeper node (larger g): fewer re-expansions.
                    heapq.heappush(heap, (g + self.h(child), -g, next(counter), child))
        return Plan(self.unwind(best), best.g, False, expanded)


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
    x, y, z = start
    search = _Search(grid, frozenset(goals), sets_per_position)
    return search.run((x, y, z), max_expansions)


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
