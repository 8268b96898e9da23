"""A* on an 8-connected occupancy grid (Algorithm 1 of the notes, with a correct decrease-key).

Grid: a boolean array ``occupied[row, col]``; cells are ``(row, col)``. Moves go to the 8
neighbours, straight moves cost 1 and diagonal moves ``sqrt(2)`` (in cells; multiply by the
resolution for metres). **No corner cutting**: a diagonal move is allowed only when both
orthogonal cells it passes between are free (a robot cannot squeeze between two obstacles that
touch at a corner, nor clip an obstacle's corner). :func:`grid_graph` builds the very same graph
as a sparse matrix for Dijkstra (:mod:`scipy.sparse.csgraph`).

Heuristic: octile distance ``h = max(dr, dc) + (sqrt(2) - 1) min(dr, dc)``, the exact path cost
on an empty grid. It is admissible (obstacles and the corner rule only remove edges, so true
costs can only be larger) and consistent (``h`` is the shortest-path metric of the full grid,
so ``h(i) <= cost(i, j) + h(j)`` for every edge), hence a node is final when it is first popped
and the closed set never has to be reopened.

Open set (:func:`astar`): a binary heap (``heapq``) with **lazy deletion**. The notes' line 13
("remove i from open") removes the wrong node and never updates ``j``; the correct decrease-key,
when a cheaper path to ``j`` is found, sets ``g(j)`` and ``parent(j)`` and pushes a new entry for
``j``; the stale, more expensive entry is skipped when it is popped (``j`` is closed by then).
The notes' loop also stops when the goal *enters* open (too early: its cost may still drop) and
reports "no path" when a node has no unclosed neighbour; here the search stops when the goal is
*popped* and reports no path only when open is empty. Ties in ``f`` prefer the smaller ``h``
(deeper nodes), which cuts the expansions on open ground and does not affect optimality.

Speed (measured, docs/planning.md): heap entries are single Python ints packing ``(f, h, node)``
(about 2.4x faster to push and pop than tuples); the inner loop is plain Python over flat
indices of a grid padded by one obstacle cell (no bounds checks), with ``g``/``parent`` in
Python lists and ``closed`` in a bytearray (scalar indexing 2-3.5x faster than into numpy
arrays). :func:`astar_banded` is the vectorised variant that the planner uses on big grids:
same graph, heuristic and optimal cost, expanding all nodes in a band of ``f`` at once.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import sparse

from gtvo.errors import InputError, show

SQRT2 = math.sqrt(2.0)

#: The 8 moves ``(d_row, d_col, cost)``; straight moves first.
MOVES: tuple[tuple[int, int, float], ...] = (
    (0, 1, 1.0), (0, -1, 1.0), (1, 0, 1.0), (-1, 0, 1.0),
    (1, 1, SQRT2), (1, -1, SQRT2), (-1, 1, SQRT2), (-1, -1, SQRT2),
)


@dataclass(frozen=True)
class PathResult:
    """Result of a grid search.

    Attributes:
        found: whether the goal is reachable.
        path: ``(K, 2)`` int array of ``(row, col)`` cells from start to goal (empty if not found).
        cost: path cost in cells (straight 1, diagonal sqrt(2)); ``inf`` if not found.
        expanded: number of nodes closed (taken from the heap as final).
    """

    found: bool
    path: NDArray[np.int64]
    cost: float
    expanded: int


def octile_distance(a: tuple[int, int], b: tuple[int, int]) -> float:
    """Octile distance between two cells: the path cost on an obstacle-free 8-connected grid."""
    dr, dc = abs(a[0] - b[0]), abs(a[1] - b[1])
    return max(dr, dc) + (SQRT2 - 1.0) * min(dr, dc)


def _check_grid(occupied: ArrayLike) -> NDArray[np.bool_]:
    grid = np.asarray(occupied)
    if grid.ndim != 2 or grid.size == 0:
        raise InputError(f"occupancy grid must be a non-empty 2-D array, got shape {grid.shape}")
    return grid.astype(bool, copy=False)


def _check_cell(name: str, cell: tuple[int, int], grid: NDArray[np.bool_]) -> tuple[int, int]:
    try:
        r, c = (int(v) for v in cell)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a (row, col) pair of integers, got {show(cell)}") from None
    if not (0 <= r < grid.shape[0] and 0 <= c < grid.shape[1]):
        raise InputError(f"{name} cell {(r, c)} is outside the {grid.shape[0]}x{grid.shape[1]} grid")
    if grid[r, c]:
        raise InputError(f"{name} cell {(r, c)} is inside an obstacle")
    return r, c


def astar(occupied: ArrayLike, start: tuple[int, int], goal: tuple[int, int]) -> PathResult:
    """Shortest 8-connected path (no corner cutting) from ``start`` to ``goal``, ``(row, col)`` cells.

    Returns a :class:`PathResult` with ``found=False`` when the goal is unreachable. Raises
    :class:`InputError` when start or goal is out of the grid or inside an obstacle.
    """
    grid = _check_grid(occupied)
    start = _check_cell("start", start, grid)
    goal = _check_cell("goal", goal, grid)
    H, W = grid.shape
    Wp = W + 2
    padded = np.ones((H + 2, Wp), dtype=bool)
    padded[1:-1, 1:-1] = grid
    free = bytearray((~padded).ravel().tobytes())  # 1 = free, 0 = obstacle or border
    n = padded.size

    def flat(cell: tuple[int, int]) -> int:
        return (cell[0] + 1) * Wp + cell[1] + 1

    s, t = flat(start), flat(goal)
    # octile heuristic to the goal for every padded cell, vectorised once
    rows, cols = np.divmod(np.arange(n), Wp)
    dr = np.abs(rows - (goal[0] + 1))
    dc = np.abs(cols - (goal[1] + 1))
    h_arr = np.maximum(dr, dc) + (SQRT2 - 1.0) * np.minimum(dr, dc)
    h = h_arr.tolist()

    # move table: (offset, cost, orthogonal offsets a diagonal passes between, or 0)
    moves = [(dr_ * Wp + dc_, cost, (dr_ * Wp if dr_ and dc_ else 0), (dc_ if dr_ and dc_ else 0))
             for dr_, dc_, cost in MOVES]
    straight = [(o, c) for o, c, a, _ in moves if a == 0]
    diagonal = [(o, c, a, b) for o, c, a, b in moves if a != 0]

    # Heap entries are single Python ints (about 3x faster to push/pop than tuples, measured):
    # key = (qf << (HB + NB)) | (qh << NB) | node, with qf = floor(f * 2^FB) where 2^FB is chosen
    # so that qf keeps the float's full precision (monotone in f, ties only within ~1 ulp), and
    # qh = floor(h * 16) the tie-break on the smaller h.
    f_bound = SQRT2 * n + float(np.max(h_arr)) + 1.0
    FB = 52 - math.ceil(math.log2(f_bound))
    scale_f = float(2.0 ** FB)
    NB = n.bit_length()
    HB = (int(np.max(h_arr) * 16.0) + 1).bit_length()
    shift_f = HB + NB
    node_mask = (1 << NB) - 1
    qh = (h_arr * 16.0).astype(np.int64)
    hkey = (qh << NB).tolist()  # (qh << NB) per node, precomputed

    inf = math.inf
    g = [inf] * n
    parent = [-1] * n
    closed = bytearray(n)
    g[s] = 0.0
    heap: list[int] = [(int(h[s] * scale_f) << shift_f) | hkey[s] | s]
    push, pop = heapq.heappush, heapq.heappop
    expanded = 0
    found = False
    while heap:
        i = pop(heap) & node_mask
        if closed[i]:
            continue  # stale entry: i was reached more cheaply and already closed
        closed[i] = 1
        expanded += 1
        if i == t:
            found = True
            break
        gi = g[i]
        for off, cost in straight:
            j = i + off
            if free[j] and not closed[j]:
                ng = gi + cost
                if ng < g[j]:  # new node or decrease-key: update cost and parent, push again
                    g[j] = ng
                    parent[j] = i
                    push(heap, (int((ng + h[j]) * scale_f) << shift_f) | hkey[j] | j)
        for off, cost, a, b in diagonal:
            j = i + off
            if free[j] and not closed[j] and free[i + a] and free[i + b]:
                ng = gi + cost
                if ng < g[j]:
                    g[j] = ng
                    parent[j] = i
                    push(heap, (int((ng + h[j]) * scale_f) << shift_f) | hkey[j] | j)
    if not found:
        return PathResult(False, np.empty((0, 2), dtype=np.int64), math.inf, expanded)
    chain = [t]
    while chain[-1] != s:
        chain.append(parent[chain[-1]])
    idx = np.array(chain[::-1], dtype=np.int64)
    path = np.column_stack([idx // Wp - 1, idx % Wp - 1])
    return PathResult(True, path, float(g[t]), expanded)


def allowed_moves(occupied: ArrayLike) -> NDArray[np.uint8]:
    """Per cell, bit ``k`` set when move ``MOVES[k]`` is allowed from it (inside the grid, target
    free, and for diagonals both orthogonal cells free: no corner cutting). Obstacles get 0."""
    grid = _check_grid(occupied)
    H, W = grid.shape
    free = ~grid
    padded = np.zeros((H + 2, W + 2), dtype=bool)
    padded[1:-1, 1:-1] = free
    mask = np.zeros((H, W), dtype=np.uint8)
    for k, (dr, dc, _) in enumerate(MOVES):
        ok = free & padded[1 + dr:1 + dr + H, 1 + dc:1 + dc + W]
        if dr and dc:
            ok &= padded[1 + dr:1 + dr + H, 1:1 + W] & padded[1:1 + H, 1 + dc:1 + dc + W]
        mask |= ok.astype(np.uint8) << np.uint8(k)
    return mask


def grid_graph(occupied: ArrayLike) -> sparse.csr_matrix:
    """The same 8-connected graph as :func:`astar` (no corner cutting) as a sparse matrix.

    Node ``r * W + c``; edge weights 1 (straight) and sqrt(2) (diagonal). Built vectorised from
    :func:`allowed_moves`.
    """
    grid = _check_grid(occupied)
    H, W = grid.shape
    mask = allowed_moves(grid).ravel()
    srcs, dsts, weights = [], [], []
    for k, (dr, dc, cost) in enumerate(MOVES):
        src = np.flatnonzero(mask & np.uint8(1 << k))
        srcs.append(src)
        dsts.append(src + dr * W + dc)
        weights.append(np.full(src.size, cost))
    return sparse.csr_matrix((np.concatenate(weights), (np.concatenate(srcs), np.concatenate(dsts))),
                             shape=(H * W, H * W))


def _unique_in_place_order(nodes: NDArray[np.int64], slot: NDArray[np.int64]) -> NDArray[np.int64]:
    """Drop repeated entries of ``nodes`` (one survivor per value) using a scratch array ``slot``."""
    pos = np.arange(nodes.size)
    slot[nodes] = pos
    return nodes[slot[nodes] == pos]


def astar_banded(occupied: ArrayLike, start: tuple[int, int], goal: tuple[int, int],
                 band: float = 2.0) -> PathResult:
    """A* that expands, vectorised, every open node whose ``f`` is within ``band`` of the minimum.

    Same graph, heuristic and result as :func:`astar` (the path may differ between equal-cost
    paths). Each round takes the open nodes with ``f < f_min + band`` and relaxes their 8 moves
    with numpy; nodes whose ``g`` drops and whose ``f`` stays below the bound are relaxed again
    (label-correcting inside the band) until nothing changes; then the band is closed. With a
    consistent heuristic every node whose optimal ``f`` is below the bound is reached optimally
    inside the band (the optimal path's ``f`` never decreases), so closed nodes are final and the
    search stops, optimal, once the goal is closed. ``band -> 0`` is plain A* by ``f``; it is
    Delta-stepping on the heuristic-reduced costs ``c(i, j) - h(i) + h(j) >= 0``.
    """
    if not (np.isfinite(band) and band > 0):
        raise InputError(f"band must be a finite positive number, got {show(band)}")
    grid = _check_grid(occupied)
    start = _check_cell("start", start, grid)
    goal = _check_cell("goal", goal, grid)
    H, W = grid.shape
    n = H * W
    mask = allowed_moves(grid).ravel()
    s = start[0] * W + start[1]
    t = goal[0] * W + goal[1]
    rows, cols = np.divmod(np.arange(n), W)
    dr = np.abs(rows - goal[0])
    dc = np.abs(cols - goal[1])
    h = np.maximum(dr, dc) + (SQRT2 - 1.0) * np.minimum(dr, dc)
    offsets = np.array([mdr * W + mdc for mdr, mdc, _ in MOVES], dtype=np.int64)
    costs = np.array([c for _, _, c in MOVES])
    bits = np.uint8(1) << np.arange(8, dtype=np.uint8)
    g = np.full(n, np.inf)
    parent = np.full(n, -1, dtype=np.int64)
    closed = np.zeros(n, dtype=bool)
    slot = np.zeros(n, dtype=np.int64)
    g[s] = 0.0
    open_nodes = np.array([s], dtype=np.int64)
    found = False
    while True:
        open_nodes = open_nodes[~closed[open_nodes]]
        if open_nodes.size == 0:
            break
        open_nodes = _unique_in_place_order(open_nodes, slot)
        f = g[open_nodes] + h[open_nodes]
        bound = f.min() + band
        in_band = f < bound
        frontier = open_nodes[in_band]
        open_nodes = open_nodes[~in_band]
        members = [frontier]
        while frontier.size:
            ok = (mask[frontier][:, None] & bits) != 0          # (k, 8) allowed moves
            dst = (frontier[:, None] + offsets)[ok]
            new_g = (g[frontier][:, None] + costs)[ok]
            # Closed nodes are final (consistent h), so new_g < g fails for them (up to a
            # harmless 1-ulp rounding "improvement"); no closed test here: measured 15 % faster.
            better = new_g < g[dst]
            if not better.any():
                break
            dst, new_g = dst[better], new_g[better]
            src = np.broadcast_to(frontier[:, None], ok.shape)[ok][better]
            np.minimum.at(g, dst, new_g)                        # decrease-key, duplicates resolved
            won = new_g == g[dst]
            improved = dst[won]
            parent[improved] = src[won]
            improved = _unique_in_place_order(improved, slot)
            inside = g[improved] + h[improved] < bound
            frontier = improved[inside]
            members.append(frontier)
            open_nodes = np.concatenate([open_nodes, improved[~inside]])
        closed[np.concatenate(members)] = True
        if closed[t]:
            found = True
            break
    expanded = int(np.count_nonzero(closed))
    if not found:
        return PathResult(False, np.empty((0, 2), dtype=np.int64), math.inf, expanded)
    chain = [t]
    while chain[-1] != s:
        chain.append(int(parent[chain[-1]]))
    idx = np.array(chain[::-1], dtype=np.int64)
    return PathResult(True, np.column_stack([idx // W, idx % W]), float(g[t]), expanded)


def path_cost(path: ArrayLike) -> float:
    """Cost in cells of a path of ``(row, col)`` cells (1 per straight step, sqrt(2) per diagonal)."""
    p = np.asarray(path, dtype=np.int64)
    if p.shape[0] < 2:
        return 0.0
    steps = np.abs(np.diff(p, axis=0))
    return float(np.sum(np.where(steps.sum(axis=1) == 2, SQRT2, 1.0)))
