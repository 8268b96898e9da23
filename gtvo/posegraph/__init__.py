"""Pose-graph optimisation: readers, GTSAM and hand-rolled solvers, two objectives.

Typical use::

    import gtvo.posegraph as pg
    graph = pg.read("parking-garage.g2o")
    result = pg.optimize(graph, solver="handrolled", init="chordal", objective="geodesic")
    print(result.gtsam_error, result.sesync_objective)
    pg.write_g2o("optimised.g2o", result.graph)

Math and names: ``docs/posegraph.md``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from gtvo.errors import InputError
from gtvo.posegraph import gtsam_solver, handrolled, information, sesync
from gtvo.posegraph.graph import PoseGraph
from gtvo.posegraph.io import check_connected, compose_spanning_tree, read, write_g2o

SOLVERS = ("gtsam", "handrolled")
INITS = gtsam_solver.INITS
OBJECTIVES = gtsam_solver.OBJECTIVES
METHODS = gtsam_solver.METHODS

__all__ = ["PoseGraph", "PoseGraphResult", "read", "write_g2o", "optimize", "gtsam_error",
           "sesync_objective", "initial_poses", "compose_spanning_tree", "SOLVERS", "INITS",
           "OBJECTIVES", "METHODS"]


def gtsam_error(graph: PoseGraph) -> float:
    """GTSAM's error ``0.5 sum ||Log(Z^-1 X_i^-1 X_j)||^2_Omega`` at the graph's poses."""
    return handrolled.gtsam_error(graph, graph.rotations, graph.translations)


def sesync_objective(graph: PoseGraph) -> float:
    """SE-Sync's ``F`` at the graph's poses."""
    return sesync.objective(graph, graph.rotations, graph.translations)


def initial_poses(graph: PoseGraph, init: str = "chordal", warn: Callable[[str], None] | None = None) -> PoseGraph:
    """The graph with initial poses by ``init`` (``file``, ``odometry``, ``chordal``; see
    :func:`gtvo.posegraph.gtsam_solver.initialise` for the fallback ``warn`` is told about)."""
    R, t, _ = gtsam_solver.initialise(information.block_diagonal(graph), init, warn)
    return graph.with_poses(R, t)


@dataclass
class PoseGraphResult:
    """An optimisation's outcome: the graph at the optimised poses and its figures."""

    graph: PoseGraph
    solver: str
    init: str
    objective: str
    method: str
    gtsam_error: float
    sesync_objective: float
    initial_gtsam_error: float
    initial_sesync_objective: float
    iterations: int
    seconds: float
    init_seconds: float
    converged: bool = True
    init_used: str = ""
    repaired_information: int = 0

    def as_dict(self) -> dict[str, object]:
        """JSON-ready summary (no poses)."""
        return {"file": self.graph.source, "dim": self.graph.dim, "poses": self.graph.num_poses,
                "edges": self.graph.num_edges, "solver": self.solver, "init": self.init,
                "init_used": self.init_used or self.init, "converged": self.converged,
                "repaired_information_edges": self.repaired_information,
                "objective": self.objective, "method": self.method, "gtsam_error": self.gtsam_error,
                "sesync_objective": self.sesync_objective, "initial_gtsam_error": self.initial_gtsam_error,
                "initial_sesync_objective": self.initial_sesync_objective, "iterations": self.iterations,
                "seconds": self.seconds, "init_seconds": self.init_seconds}


def optimize(graph: PoseGraph, solver: str = "gtsam", init: str = "chordal", objective: str = "geodesic",
             method: str = "lm", max_iterations: int = 100, rel_tol: float = 1e-10, abs_tol: float = 1e-12,
             progress: Callable[[int, float], None] | None = None, strict: bool = False,
             warn: Callable[[str], None] | None = None) -> PoseGraphResult:
    """Optimise ``graph`` and return a :class:`PoseGraphResult`.

    ``solver``: ``gtsam`` (GTSAM's C++ optimisers) or ``handrolled`` (the notes' GN/LM in numpy/scipy;
    ``method`` ``lm`` or ``gn``). ``init``: ``file``, ``odometry``, ``chordal`` (which falls back to
    ``odometry`` when GTSAM gives up on it: ``init_used``). ``objective``: ``geodesic`` (GTSAM's) or
    ``sesync``. ``seconds`` is the optimiser's time, ``init_seconds`` the initialisation's;
    ``converged`` is False when the iteration cap stopped the run.

    Information matrices that are not positive definite (their translation and rotation blocks
    are, :meth:`PoseGraph.validate`): ``strict`` refuses them; otherwise the SE-Sync objective
    uses them as they are (it reads only those blocks) and the geodesic objective replaces each
    by the nearest positive-definite matrix (:mod:`gtvo.posegraph.information`), and ``warn`` is
    told how many in one line. The reported ``gtsam_error`` uses the repaired matrices with either
    objective (``repaired_information`` counts them); the initialisation drops their cross terms
    (:func:`gtvo.posegraph.information.block_diagonal`).
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r} (choose from {', '.join(SOLVERS)})")
    if objective not in OBJECTIVES:
        raise InputError(f"unknown objective {objective!r} (choose from {', '.join(OBJECTIVES)})")
    if method not in METHODS or (solver == "handrolled" and method == "dogleg"):
        raise InputError(f"unknown method {method!r} for solver {solver}")
    graph.validate()
    check_connected(graph)
    if strict:
        information.refuse_not_positive_definite(graph)
    pd_graph, repaired = information.repaired(graph)
    if repaired and objective == "geodesic" and warn is not None:
        warn(f"{repaired} of {graph.num_edges} information matrices are not positive definite: each replaced "
             "by the nearest positive-definite matrix (--strict refuses them)")
    solve_graph = pd_graph if objective == "geodesic" else graph
    start = time.perf_counter()
    R0, t0, init_used = gtsam_solver.initialise(information.block_diagonal(graph), init, warn)
    init_seconds = time.perf_counter() - start
    g0 = pd_graph.with_poses(R0, t0)
    if solver == "gtsam":
        res = gtsam_solver.optimize(solve_graph, R0, t0, objective, method, max_iterations, rel_tol, abs_tol)
        R, t, iterations, seconds, converged = res.rotations, res.translations, res.iterations, res.seconds, \
            res.converged
    else:
        hres = handrolled.optimize(solve_graph, R0, t0, objective, method, max_iterations, rel_tol, abs_tol,
                                   progress=progress)
        R, t, iterations, seconds, converged = hres.rotations, hres.translations, hres.iterations, hres.seconds, \
            hres.converged
    out = pd_graph.with_poses(R, t)
    if not converged and warn is not None:
        warn(f"not converged after {iterations} iteration{'' if iterations == 1 else 's'} (raise --max-iterations)")
    return PoseGraphResult(graph.with_poses(R, t), solver, init, objective, method, gtsam_error(out),
                           sesync.objective(graph, R, t), gtsam_error(g0), sesync.objective(graph, R0, t0),
                           iterations, seconds, init_seconds, converged, init_used, repaired)
