"""The A* search of ``astar.plan``, compiled with numba: the same nodes, order and answer as
the search it replaced (``astar``'s docstring has the rules), 22 times faster on the
diamond tree's searches (``python bench/astar_search.py``).

A search that cannot reach its goal spends its whole budget, thousands of expansions, and
the tree plans every tick it is not memoised: in Python such searches were half the CPU
of a world (the tree and its world server).

Nodes live in flat arrays (their parent, position, the block destroyed to reach them, the
nearest destroy node among their ancestors, cost so far, Zobrist key of the destroyed
set). A position is a flat cell index; the start, when it lies outside the grid, has the
extra index ``ncells``. Expanding a node stamps its destroyed blocks once (a walk up its
chain), so each cell it looks at is one array read. ``search`` returns the node the plan
ends at; ``astar`` unwinds it into steps.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Cell categories of the planning grid, the costs and the moves (``astar`` re-exports them).
FREE, SOLID, HARD, WATER, LAVA = 0, 1, 2, 3, 4
MOVE_COST = 1.0
JUMP_COST = 2.0
DESTROY_COST = 5.0
MAX_DROP = 3  # blocks; Minecraft's fall damage is ceil(d - 3)
HORIZONTAL: tuple[tuple[int, int], ...] = ((1, 0), (-1, 0), (0, 1), (0, -1))
NODES_PER_EXPANSION = 31
"""At most: 4 sides × (a jump with 3 destroys and a walk with 2, each with its arrival)
plus digging down (one destroy, one arrival); and the root."""


@numba.njit(inline="always")
def _slot(keys_pos, keys_z, p, z):
    """The slot of key (position ``p``, Zobrist key ``z``) in an open-addressing table (a
    power of two in size, positions -1 where empty): where it is, or where it would go."""
    mask = keys_pos.shape[0] - 1
    s = (z ^ (p * 0x27D4EB2F165667C5)) & mask
    while keys_pos[s] != -1 and (keys_pos[s] != p or keys_z[s] != z):
        s = (s + 1) & mask
    return s


@numba.njit(inline="always")
def _before(f, g, a, b):
    """Open-list order of nodes ``a`` and ``b``: lower f, then larger g, then the one pushed
    first (a lower index: nodes are pushed in the order they are made)."""
    if f[a] != f[b]:
        return f[a] < f[b]
    if g[a] != g[b]:
        return g[a] > g[b]
    return a < b


@numba.njit(inline="always")
def _push(heap, size, node, f, g):
    """Adds ``node`` to the binary heap of ``size`` nodes; the new size."""
    i = size
    while i > 0:
        up = (i - 1) // 2
        if not _before(f, g, node, heap[up]):
            break
        heap[i] = heap[up]
        i = up
    heap[i] = node
    return size + 1


@numba.njit(inline="always")
def _pop(heap, size, f, g):
    """Removes the first node of the heap and returns it (the new size is ``size - 1``)."""
    first = heap[0]
    size -= 1
    last = heap[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        if child + 1 < size and _before(f, g, heap[child + 1], heap[child]):
            child += 1
        if not _before(f, g, heap[child], last):
            break
        heap[i] = heap[child]
        i = child
    heap[i] = last
    return first


@numba.njit(inline="always")
def _cat(x, y, z, dims, cells, stamp, mark):
    """Category of cell (x, y, z) in the state being expanded (a solid block whose stamp is
    ``mark`` is destroyed in it); outside the grid: hard."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    if not (0 <= x < nx and 0 <= y < ny and 0 <= z < nz):
        return HARD
    i = (y * nz + z) * nx + x
    k = cells[i]
    if k == SOLID and stamp[i] == mark:
        return FREE
    return k


@numba.njit(inline="always")
def _blockers(cs, count, dims, cells, breakable, stamp, mark, out):
    """The solid cells among the first ``count`` rows of ``cs`` to destroy, in order,
    written to ``out``: their number, or -1 when one of them cannot be destroyed."""
    m = 0
    for j in range(count):
        x, y, z = cs[j, 0], cs[j, 1], cs[j, 2]
        k = _cat(x, y, z, dims, cells, stamp, mark)
        if k == FREE:
            continue
        if k != SOLID:
            return -1
        i = (y * dims[2] + z) * dims[0] + x  # solid: inside the grid
        if breakable[i] != 1:
            return -1
        out[m] = i
        m += 1
    return m


@numba.njit(inline="always")
def _landing(x, y, z, dims, cells, stamp, mark):
    """The y where a body whose feet enter free cell (x, y, z) comes to rest, or -1 for a
    drop longer than MAX_DROP, into a liquid, or off the grid."""
    for d in range(MAX_DROP + 1):
        under = _cat(x, y - d - 1, z, dims, cells, stamp, mark)
        if _cat(x, y - d, z, dims, cells, stamp, mark) != FREE:
            return -1
        if under == SOLID or under == HARD:
            return y - d
        if under != FREE:
            return -1
    return -1


@numba.njit(inline="always")
def _h(p, xyz, opened, n_opened, known, terms, bound, goals, goal_solid_count):
    """Admissible cost-to-go at position ``p`` (cell ``xyz``): per goal, ``astar.heuristic``
    plus 5 per solid block in the goal's own two cells not destroyed yet (``opened``
    counts the destroyed ones per goal); the least over the goals. Each position's terms
    with nothing destroyed are computed once."""
    if not known[p]:
        x, y, z = xyz[0], xyz[1], xyz[2]
        least = np.inf
        for k in range(goals.shape[0]):
            hd = abs(goals[k, 0] - x) + abs(goals[k, 2] - z)
            dy = goals[k, 1] - y
            if dy > 0:
                h = JUMP_COST * dy + max(0, hd - dy) * MOVE_COST
            else:
                h = max(hd, math.ceil(-dy / MAX_DROP)) * MOVE_COST
            terms[p, k] = h + DESTROY_COST * goal_solid_count[k]
            least = min(least, terms[p, k])
        bound[p] = least
        known[p] = True
    if n_opened == 0:
        return bound[p]
    least = np.inf
    for k in range(goals.shape[0]):
        least = min(least, terms[p, k] - DESTROY_COST * opened[k])
    return least


@numba.njit(inline="always")
def _open(i, step, goal_solid, goal_solid_pairs, opened):
    """Counts block ``i`` destroyed (``step`` 1) or not any more (-1) in ``opened`` when it
    is a goal's own block; how many goals' counts changed."""
    if not goal_solid[i]:
        return 0
    changed = 0
    for r in range(goal_solid_pairs.shape[0]):
        if goal_solid_pairs[r, 0] == i:
            opened[goal_solid_pairs[r, 1]] += step
            changed += 1
    return changed


# long-function: a compiled kernel (numba), one loop kept whole so that it compiles to one.
@numba.njit(cache=True, nogil=True)
def search(
    dims, cells, breakable, zobrist, start, goals, goal_solid_count, goal_solid_pairs,
    max_expansions, sets_per_position,
):  # fmt: skip
    """A* from ``start`` (x, y, z) to any row of ``goals``.

    Args:
        dims: (nx, ny, nz).
        cells: planning categories, flat in Malmo order; ``breakable``: 1 per solid cell no
            liquid touches.
        zobrist: one key per cell.
        goals: (G, 3) goal cells; ``goal_solid_count``: solid blocks in each goal's two cells;
            ``goal_solid_pairs``: (cell, goal) rows, one per such block.

    Returns:
        (the node the plan ends at, whether it is a goal, nodes expanded, and the node
        arrays: parent, position, destroyed block (-1 for a move), cost so far).
    """
    nx, ny, nz = dims[0], dims[1], dims[2]
    ncells = nx * ny * nz
    sx, sy, sz = start[0], start[1], start[2]
    inside = 0 <= sx < nx and 0 <= sy < ny and 0 <= sz < nz
    start_id = (sy * nz + sz) * nx + sx if inside else ncells
    n_goals = goals.shape[0]

    is_goal = np.zeros(ncells + 1, dtype=np.bool_)
    for k in range(n_goals):
        gx, gy, gz = goals[k, 0], goals[k, 1], goals[k, 2]
        if 0 <= gx < nx and 0 <= gy < ny and 0 <= gz < nz:
            is_goal[(gy * nz + gz) * nx + gx] = True
        elif gx == sx and gy == sy and gz == sz:
            is_goal[ncells] = True
    goal_solid = np.zeros(ncells, dtype=np.bool_)
    for r in range(goal_solid_pairs.shape[0]):
        goal_solid[goal_solid_pairs[r, 0]] = True

    capacity = max_expansions * NODES_PER_EXPANSION + 1
    parent = np.empty(capacity, dtype=np.int32)
    pos = np.empty(capacity, dtype=np.int32)
    broken = np.empty(capacity, dtype=np.int32)
    last_destroy = np.empty(capacity, dtype=np.int32)  # the nearest destroy node, or -1
    g = np.empty(capacity)
    zkey = np.empty(capacity, dtype=np.int64)
    parent[0], pos[0], broken[0], last_destroy[0], g[0], zkey[0] = -1, start_id, -1, -1, 0.0, 0
    size = 1
    if n_goals == 0:
        return 0, False, 0, parent[:1], pos[:1], broken[:1], g[:1]

    # Positions' cells, and their heuristic terms with nothing destroyed, once each.
    xyz = np.empty((ncells + 1, 3), dtype=np.int64)
    for p in range(ncells):
        xyz[p, 0], xyz[p, 1], xyz[p, 2] = p % nx, (p // nx) // nz, (p // nx) % nz
    xyz[ncells, 0], xyz[ncells, 1], xyz[ncells, 2] = sx, sy, sz
    known = np.zeros(ncells + 1, dtype=np.bool_)
    terms = np.empty((ncells + 1, n_goals))
    bound = np.empty(ncells + 1)
    expansions_at = np.zeros(ncells + 1, dtype=np.int64)
    # The destroyed set of the node being expanded: blocks stamped with its mark; per goal,
    # how many of its own blocks are among them.
    stamp = np.full(ncells, -1, dtype=np.int64)
    opened = np.zeros(n_goals, dtype=np.int64)

    # The cheapest cost found per (position, destroyed set): an open-addressing table with
    # room for every arrival node (at most 9 a expansion).
    table = 1 << int(math.ceil(math.log2(2 * (9 * max_expansions + 1))))
    keys_pos = np.full(table, -1, dtype=np.int64)
    keys_z = np.empty(table, dtype=np.int64)
    best_g = np.empty(table)
    s = _slot(keys_pos, keys_z, start_id, 0)
    keys_pos[s], keys_z[s], best_g[s] = start_id, 0, 0.0
    # The open list: a binary heap of nodes, ordered by their f (kept per node) and g.
    heap = np.empty(capacity, dtype=np.int64)
    f = np.empty(capacity)

    blocks = np.empty(3, dtype=np.int64)
    cs = np.empty((3, 3), dtype=np.int64)
    opt_blocks = np.empty((9, 3), dtype=np.int64)
    opt_count = np.empty(9, dtype=np.int64)
    opt_target = np.empty((9, 3), dtype=np.int64)
    opt_cost = np.empty(9)

    h0 = _h(start_id, xyz[start_id], opened, 0, known, terms, bound, goals, goal_solid_count)
    f[0] = h0
    open_size = _push(heap, 0, 0, f, g)
    best, best_h = 0, h0
    expanded = 0
    mark = -1
    while open_size > 0 and expanded < max_expansions:
        n = _pop(heap, open_size, f, g)
        open_size -= 1
        p = pos[n]
        s = _slot(keys_pos, keys_z, p, zkey[n])
        if keys_pos[s] != -1 and best_g[s] < g[n]:
            continue  # a stale entry
        if is_goal[p]:
            return n, True, expanded, parent[:size], pos[:size], broken[:size], g[:size]
        if expansions_at[p] >= sets_per_position:
            continue
        expansions_at[p] += 1
        expanded += 1

        mark += 1
        opened[:] = 0
        n_opened = 0
        d = last_destroy[n]
        while d != -1:
            stamp[broken[d]] = mark
            n_opened += _open(broken[d], 1, goal_solid, goal_solid_pairs, opened)
            q = parent[d]
            d = last_destroy[q] if q != -1 else -1
        h_n = _h(p, xyz[p], opened, n_opened, known, terms, bound, goals, goal_solid_count)
        if h_n < best_h or (h_n == best_h and g[n] < g[best]):
            best, best_h = n, h_n

        # The moves from n: (blocks to destroy first, top first; target; cost).
        x, y, z = xyz[p, 0], xyz[p, 1], xyz[p, 2]
        options = 0
        for side in range(4):
            dx, dz = HORIZONTAL[side]
            fx, fz = x + dx, z + dz
            feet = _cat(fx, y, fz, dims, cells, stamp, mark)
            if feet == SOLID or feet == HARD:
                # Jump onto the obstacle: head room above us and two free cells above it.
                cs[0, 0], cs[0, 1], cs[0, 2] = x, y + 2, z
                cs[1, 0], cs[1, 1], cs[1, 2] = fx, y + 2, fz
                cs[2, 0], cs[2, 1], cs[2, 2] = fx, y + 1, fz
                m = _blockers(cs, 3, dims, cells, breakable, stamp, mark, blocks)
                if m >= 0:
                    opt_blocks[options, :m] = blocks[:m]
                    opt_count[options] = m
                    opt_target[options, 0], opt_target[options, 1] = fx, y + 1
                    opt_target[options, 2], opt_cost[options] = fz, JUMP_COST
                    options += 1
            cs[0, 0], cs[0, 1], cs[0, 2] = fx, y + 1, fz
            cs[1, 0], cs[1, 1], cs[1, 2] = fx, y, fz
            m = _blockers(cs, 2, dims, cells, breakable, stamp, mark, blocks)
            if m >= 0:
                opt_blocks[options, :m] = blocks[:m]
                opt_count[options] = m
                opt_target[options, 0], opt_target[options, 1] = fx, y
                opt_target[options, 2], opt_cost[options] = fz, MOVE_COST
                options += 1
        cs[0, 0], cs[0, 1], cs[0, 2] = x, y - 1, z
        m = _blockers(cs, 1, dims, cells, breakable, stamp, mark, blocks)
        if m >= 0:
            opt_blocks[options, :m] = blocks[:m]
            opt_count[options] = m
            opt_target[options, 0], opt_target[options, 1] = x, y - 1
            opt_target[options, 2], opt_cost[options] = z, MOVE_COST
            options += 1

        # Each move's arrival, its destroy nodes chained in between (the move's blocks are
        # stamped destroyed while its landing and h are found, then not any more).
        for o in range(options):
            c = n
            more = 0
            for j in range(opt_count[o]):
                i = opt_blocks[o, j]
                parent[size], pos[size], broken[size], last_destroy[size] = c, pos[c], i, size
                g[size], zkey[size] = g[c] + DESTROY_COST, zkey[c] ^ zobrist[i]
                c = size
                size += 1
                stamp[i] = mark
                more += _open(i, 1, goal_solid, goal_solid_pairs, opened)
            tx, ty, tz = opt_target[o, 0], opt_target[o, 1], opt_target[o, 2]
            land = _landing(tx, ty, tz, dims, cells, stamp, mark)
            # A jump must land on the obstacle.
            if land != -1 and (opt_cost[o] != JUMP_COST or land == ty):
                child = size
                parent[child], pos[child], broken[child] = c, (land * nz + tz) * nx + tx, -1
                last_destroy[child] = last_destroy[c]
                g[child], zkey[child] = g[c] + opt_cost[o], zkey[c]
                size += 1
                s = _slot(keys_pos, keys_z, pos[child], zkey[child])
                if keys_pos[s] == -1 or g[child] < best_g[s]:
                    keys_pos[s], keys_z[s], best_g[s] = pos[child], zkey[child], g[child]
                    f[child] = g[child] + _h(pos[child], xyz[pos[child]], opened,
                                             n_opened + more, known, terms, bound, goals,
                                             goal_solid_count)  # fmt: skip
                    # Ties on f go to the deeper node (larger g): fewer re-expansions.
                    open_size = _push(heap, open_size, child, f, g)
            for j in range(opt_count[o]):
                i = opt_blocks[o, j]
                stamp[i] = -1
                _open(i, -1, goal_solid, goal_solid_pairs, opened)
    return best, False, expanded, parent[:size], pos[:size], broken[:size], g[:size]
