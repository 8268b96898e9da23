"""A* on a 1000x1000 grid with 20 % obstacles against scipy's C Dijkstra, in one run.

    python benchmarks/astar_speed.py [--size 1000] [--density 0.2] [--repeats 5] [--seed 0]

Times are wall-clock; the machine is shared, so the figures that matter are the ratios to the
Dijkstra time measured in the same run (searches interleaved, minimum and median over repeats).
Graph building: scipy's Dijkstra is timed on a ready CSR matrix (its build, timed separately, is
excluded); each A* time includes all of its own set-up (heuristic array, move masks). That
favours Dijkstra. Dijkstra solves single-source to all nodes (scipy has no target stop).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.sparse.csgraph import dijkstra

from gtvo.planning.astar import astar, astar_banded, grid_graph


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1000)
    ap.add_argument("--density", type=float, default=0.2)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = args.size
    rng = np.random.default_rng(args.seed)
    occ = rng.random((n, n)) < args.density
    queries = {"corner to corner": ((0, 0), (n - 1, n - 1)),
               "quarter to 3/4": ((n // 4, n // 4), (3 * n // 4, 3 * n // 4))}
    for s, g in queries.values():
        occ[s] = occ[g] = False
    t0 = time.perf_counter()
    graph = grid_graph(occ)
    build = time.perf_counter() - t0
    print(f"grid {n}x{n}, {args.density:.0%} obstacles, {graph.nnz} edges; CSR build {build:.3f} s (excluded)")
    print("| query | search | min s | median s | min / Dijkstra min | cost | expanded |")
    print("|---|---|---|---|---|---|---|")
    for qname, (s, g) in queries.items():
        times: dict[str, list[float]] = {"scipy Dijkstra (C)": [], "astar (heap)": [], "astar_banded": []}
        results = {}
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            dist = dijkstra(graph, indices=s[0] * n + s[1])
            times["scipy Dijkstra (C)"].append(time.perf_counter() - t0)
            results["scipy Dijkstra (C)"] = (float(dist[g[0] * n + g[1]]), int(np.isfinite(dist).sum()))
            for name, fn in (("astar (heap)", astar), ("astar_banded", astar_banded)):
                t0 = time.perf_counter()
                r = fn(occ, s, g)
                times[name].append(time.perf_counter() - t0)
                results[name] = (r.cost, r.expanded)
        ref = min(times["scipy Dijkstra (C)"])
        for name, v in times.items():
            cost, expanded = results[name]
            print(f"| {qname} | {name} | {min(v):.3f} | {np.median(v):.3f} | {min(v) / ref:.2f} | {cost:.6f} | {expanded} |")
        costs = {round(c, 9) for c, _ in results.values()}
        assert len(costs) == 1, f"costs disagree: {results}"


if __name__ == "__main__":
    main()
