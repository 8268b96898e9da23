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
from gtvo.posegraph import gtsam_solver, handrolled, sesync
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


def initial_poses(graph: PoseGraph, init: str = "chordal") -> PoseGraph:
    """The graph with initial poses by ``init`` (``file``, ``odometry``, ``chordal``)."""
    return graph.with_poses(*gtsam_solver.initial_poses(graph, init))


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

    def as_dict(self) -> dict[str, object]:
        """JSON-ready summary (no poses)."""
        return {"file": self.graph.source, "dim": self.graph.dim, "poses": self.graph.num_poses,
                "edges": self.graph.num_edges, "solver": self.solver, "init": self.init,
                "objective": self.objective, "method": self.method, "gtsam_error": self.gtsam_error,
                "sesync_objective": self.sesync_objective, "initial_gtsam_error": self.initial_gtsam_error,
                "initial_sesync_objective": self.initial_sesync_objective, "iterations": self.iterations,
                "seconds": self.seconds, "init_seconds": self.init_seconds}


def optimize(graph: PoseGraph, solver: str = "gtsam", init: str = "chordal", objective: str = "geodesic",
             method: str = "lm", max_iterations: int = 100, rel_tol: float = 1e-10, abs_tol: float = 1e-12,
             progress: Callable[[int, float], None] | None = None) -> PoseGraphResult:
    """Optimise ``graph`` and return a :class:`PoseGraphResult`.

    ``solver``: ``gtsam`` (GTSAM's C++ optimisers) or ``handrolled`` (the notes' GN/LM in numpy/scipy;
    ``method`` ``lm`` or ``gn``). ``init``: ``file``, ``odometry``, ``chordal``. ``objective``:
    ``geodesic`` (GTSAM's) or ``sesync``. ``seconds`` is the optimiser's time, ``init_seconds`` the
    initialisation's.
    """
    if solver not in SOLVERS:
        raise InputError(f"unknown solver {solver!r} (choose from {', '.join(SOLVERS)})")
    if objective not in OBJECTIVES:
        raise InputError(f"unknown objective {objective!r} (choose from {', '.join(OBJECTIVES)})")
    if method not in METHODS or (solver == "handrolled" and method == "dogleg"):
        raise InputError(f"unknown method {method!r} for solver {solver}")
    graph.validate()
    check_connected(graph)
    start = time.perf_counter()
    R0, t0 = gtsam_solver.initial_poses(graph, init)
    init_seconds = time.perf_counter() - start
    g0 = graph.with_poses(R0, t0)
    if solver == "gtsam":
        res = gtsam_solver.optimize(graph, R0, t0, objective, method, max_iterations, rel_tol, abs_tol)
        R, t, iterations, seconds = res.rotations, res.translations, res.iterations, res.seconds
    else:
        hres = handrolled.optimize(graph, R0, t0, objective, method, max_iterations, rel_tol, abs_tol,
                                   progress=progress)
        R, t, iterations, seconds = hres.rotations, hres.translations, hres.iterations, hres.seconds
    out = graph.with_poses(R, t)
    return PoseGraphResult(out, solver, init, objective, method, gtsam_error(out), sesync_objective(out),
                           gtsam_error(g0), sesync_objective(g0), iterations, seconds, init_seconds)
