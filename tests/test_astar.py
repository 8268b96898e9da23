"""A* (heap, Algorithm 1 with a correct decrease-key) and its banded vectorised twin against Dijkstra."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import dijkstra

from gtvo.errors import InputError
from gtvo.planning.astar import (
    MOVES,
    SQRT2,
    allowed_moves,
    astar,
    astar_banded,
    grid_graph,
    octile_distance,
    path_cost,
)

SEARCHES = {"heap": astar, "banded": astar_banded,
            "banded_narrow": lambda o, s, g: astar_banded(o, s, g, band=0.3),
            "banded_wide": lambda o, s, g: astar_banded(o, s, g, band=7.5)}


def _assert_valid(path: np.ndarray, occ: np.ndarray, start, goal) -> None:
    assert tuple(path[0]) == tuple(start) and tuple(path[-1]) == tuple(goal)
    assert np.all((path >= 0) & (path < occ.shape)), "path leaves the grid"
    assert not occ[path[:, 0], path[:, 1]].any(), "path enters an obstacle"
    steps = np.diff(path, axis=0)
    assert np.all(np.abs(steps).max(axis=1) == 1), "steps must go to one of the 8 neighbours"
    diag = np.all(steps != 0, axis=1)
    # no corner cutting: both orthogonal cells of a diagonal step are free
    a = path[:-1][diag] + np.column_stack([steps[diag, 0], np.zeros(diag.sum(), int)])
    b = path[:-1][diag] + np.column_stack([np.zeros(diag.sum(), int), steps[diag, 1]])
    assert not occ[a[:, 0], a[:, 1]].any() and not occ[b[:, 0], b[:, 1]].any(), "diagonal cuts a corner"


def _dijkstra_cost(occ: np.ndarray, start, goal) -> float:
    W = occ.shape[1]
    return float(dijkstra(grid_graph(occ), indices=start[0] * W + start[1])[goal[0] * W + goal[1]])


@pytest.mark.parametrize("name", list(SEARCHES))
def test_random_grids_cost_equals_dijkstra(name):
    search = SEARCHES[name]
    rng = np.random.default_rng(42)
    found = unreachable = 0
    for _ in range(150):
        H, W = rng.integers(1, 30, 2)
        occ = rng.random((H, W)) < rng.uniform(0.0, 0.45)
        free = np.argwhere(~occ)
        if len(free) == 0:
            continue
        start = tuple(free[rng.integers(len(free))])
        goal = tuple(free[rng.integers(len(free))])
        expected = _dijkstra_cost(occ, start, goal)
        res = search(occ, start, goal)
        assert res.found == np.isfinite(expected)
        if res.found:
            found += 1
            assert res.cost == pytest.approx(expected, abs=1e-9)
            assert path_cost(res.path) == pytest.approx(expected, abs=1e-9)
            _assert_valid(res.path, occ, start, goal)
        else:
            unreachable += 1
            assert res.cost == math.inf and res.path.shape == (0, 2)
    assert found > 50 and unreachable > 5  # both outcomes exercised


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 40), st.integers(2, 40), st.floats(0.0, 0.5))
def test_property_heap_and_banded_agree_with_dijkstra(seed, H, W, density):
    rng = np.random.default_rng(seed)
    occ = rng.random((H, W)) < density
    occ[0, 0] = occ[-1, -1] = False
    expected = _dijkstra_cost(occ, (0, 0), (H - 1, W - 1))
    for search in (astar, astar_banded):
        res = search(occ, (0, 0), (H - 1, W - 1))
        assert res.found == np.isfinite(expected)
        if res.found:
            assert res.cost == pytest.approx(expected, abs=1e-9)
            _assert_valid(res.path, occ, (0, 0), (H - 1, W - 1))


def test_open_grid_is_the_octile_distance_and_heuristic_is_consistent():
    occ = np.zeros((20, 30), dtype=bool)
    res = astar(occ, (2, 3), (17, 25))
    assert res.cost == pytest.approx(octile_distance((2, 3), (17, 25)), abs=1e-12)
    # consistency h(i) <= c(i, j) + h(j) on every allowed edge of a random grid
    rng = np.random.default_rng(0)
    occ = rng.random((25, 25)) < 0.3
    goal = (24, 24)
    mask = allowed_moves(occ)
    for k, (dr, dc, cost) in enumerate(MOVES):
        rows, cols = np.nonzero(mask & np.uint8(1 << k))
        for r, c in zip(rows, cols):
            assert octile_distance((r, c), goal) <= cost + octile_distance((r + dr, c + dc), goal) + 1e-12


def test_no_corner_cutting_between_diagonal_obstacles():
    occ = np.array([[0, 1],
                    [1, 0]], dtype=bool)
    for search in (astar, astar_banded):
        res = search(occ, (0, 0), (1, 1))
        assert not res.found and res.cost == math.inf
    assert grid_graph(occ).nnz == 0
    # one free side: the diagonal is still forbidden, the path goes around
    occ = np.array([[0, 1],
                    [0, 0]], dtype=bool)
    res = astar(occ, (0, 0), (1, 1))
    assert res.found and res.cost == pytest.approx(2.0)


def test_walled_off_goal_is_not_found():
    occ = np.zeros((10, 10), dtype=bool)
    occ[:, 5] = True
    for search in (astar, astar_banded):
        res = search(occ, (0, 0), (9, 9))
        assert not res.found and res.expanded == 50  # searched the whole left half


def test_start_equals_goal():
    res = astar(np.zeros((3, 3), bool), (1, 1), (1, 1))
    assert res.found and res.cost == 0.0 and res.path.tolist() == [[1, 1]]
    assert astar_banded(np.zeros((3, 3), bool), (1, 1), (1, 1)).cost == 0.0


@pytest.mark.parametrize("start,goal", [((-1, 0), (2, 2)), ((0, 0), (3, 0)), ((1, 1), (2, 2)), ((0, 0), (1, 1))])
def test_bad_start_goal(start, goal):
    occ = np.zeros((3, 3), dtype=bool)
    occ[1, 1] = True
    for search in (astar, astar_banded):
        with pytest.raises(InputError):
            search(occ, start, goal)


def test_bad_grid_and_band():
    with pytest.raises(InputError):
        astar(np.zeros((0, 3), bool), (0, 0), (0, 1))
    with pytest.raises(InputError):
        astar(np.zeros(5, bool), (0, 0), (0, 1))
    with pytest.raises(InputError):
        astar_banded(np.zeros((3, 3), bool), (0, 0), (2, 2), band=0.0)
    with pytest.raises(InputError):
        astar(np.zeros((3, 3), bool), ("a", 0), (2, 2))
    assert path_cost([[0, 0], [1, 1], [1, 2]]) == pytest.approx(SQRT2 + 1)
