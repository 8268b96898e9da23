"""Large generated pose graphs on which GTSAM's chordal initialisation gives up (issue 20, item 5).

Usage::

    python benchmarks/posegraph_faults.py [--sizes 10000 100000] [--max-iterations 10] [--dim 2]

For each size ``n``: the chain of ``tests/_posegraph_synthetic.chain_with_loops`` (``n`` poses,
``2n`` edges: the odometry chain plus ``n + 1`` loop edges ``(i, i + 2)``, translation precision
1e6, rotation precision 1, seed 0). Prints one markdown row: how long GTSAM's LAGO /
InitializePose3 took to throw, then ``pg.optimize`` with ``--init chordal`` (which falls back
to the odometry initialisation) and the given iteration cap: whether it fell back, iterations,
converged, GTSAM error before and after, seconds of the initialisation and of the optimiser.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import gtvo.posegraph as pg  # noqa: E402
from _posegraph_synthetic import chain_with_loops  # noqa: E402
from gtvo.posegraph import gtsam_solver  # noqa: E402


def row(n: int, dim: int, max_iterations: int) -> str:
    """One table row for a chain of ``n`` poses."""
    start = time.perf_counter()
    g = chain_with_loops(n, dim, seed=0)
    gen = time.perf_counter() - start
    start = time.perf_counter()
    try:
        gtsam_solver.chordal_poses(g)
        chordal = f"worked ({time.perf_counter() - start:.2f} s)"
    except RuntimeError as exc:
        chordal = f"threw after {time.perf_counter() - start:.2f} s (near {gtsam_solver.indeterminate_near(exc)})"
    warnings: list[str] = []
    res = pg.optimize(g, init="chordal", max_iterations=max_iterations, warn=warnings.append)
    return (f"| {n} | {g.num_edges} | {dim}-D | {gen:.1f} | {chordal} | {res.init_used} | {res.iterations} | "
            f"{res.converged} | {res.initial_gtsam_error:.6g} | {res.gtsam_error:.6g} | {res.init_seconds:.2f} | "
            f"{res.seconds:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10000, 100000])
    ap.add_argument("--max-iterations", type=int, default=10)
    ap.add_argument("--dim", type=int, choices=(2, 3), default=2)
    args = ap.parse_args()
    print("| poses | edges | dim | generate s | GTSAM chordal | init used | iterations | converged | "
          "initial error | final error | init s | optimiser s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        print(row(n, args.dim, args.max_iterations), flush=True)


if __name__ == "__main__":
    main()
