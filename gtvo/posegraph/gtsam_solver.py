"""GTSAM side: BetweenFactorPose2/3 (or SE-Sync's chordal cost) graphs, LM / GN / Dogleg, initialisations.

* Geodesic objective: ``BetweenFactorPose2/3`` with a Gaussian noise model from the file's
  full information matrix (GTSAM's ``0.5 sum ||Log(Z^-1 X_i^-1 X_j)||^2_Omega``).
* SE-Sync objective: ``FrobeniusBetweenFactorPose2/3`` (native C++), whose residual is
  ``vec(T_j - T_i Z)`` of the homogeneous matrices, column-major: the entries of
  ``R_j - R_i R~`` and ``t_j - t_i - R_i t~`` plus constant zeros. A diagonal noise model with
  precisions ``2 kappa`` on the rotation entries and ``2 tau`` on the translation entries makes
  GTSAM's ``0.5 ||r||^2`` equal to SE-Sync's ``F`` exactly (no Python factor, no Values copies).
* The gauge is fixed by a prior on ``x_0`` with sigma 1e-6 (reported errors exclude it).
* Initialisations: ``file`` (the vertices), ``odometry`` (edges composed along a spanning tree),
  ``chordal`` (LAGO ``gtsam.lago.initialize`` in 2-D on a diagonal-information copy of the
  graph, over the odometric path or, when an edge (i, i+1) is missing as in ais2klinik, over
  GTSAM's own spanning tree; ``gtsam.InitializePose3.initialize`` in 3-D). When GTSAM's sparse
  Cholesky declares that linear system indeterminate (:func:`initialise`), the odometry
  initialisation is used instead and a callback is told so in one line.
* GTSAM's optimisers are stepped here (``iterate`` until GTSAM's own ``checkConvergence``), so a
  run that stops at its iteration cap is known as such (``GtsamResult.converged``).
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Callable

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import pose_key
from gtvo.errors import InputError
from gtvo.posegraph import sesync
from gtvo.posegraph.graph import PoseGraph
from gtvo.posegraph.io import compose_spanning_tree

F64 = NDArray[np.float64]
INITS = ("file", "odometry", "chordal")
METHODS = ("lm", "gn", "dogleg")
OBJECTIVES = ("geodesic", "sesync")
PRIOR_SIGMA = 1e-6


def key(k: int) -> int:
    """GTSAM key of pose-graph node ``k`` (:func:`gtvo.core.keys.pose_key`)."""
    return pose_key(k)


def to_values(graph: PoseGraph, R: F64, t: F64) -> gtsam.Values:
    """``gtsam.Values`` of Pose2/Pose3 from stacked rotations and translations."""
    v = gtsam.Values()
    if graph.dim == 2:
        th = np.arctan2(R[:, 1, 0], R[:, 0, 0])
        for k in range(graph.num_poses):
            v.insert(key(k), gtsam.Pose2(float(t[k, 0]), float(t[k, 1]), float(th[k])))
    else:
        for k in range(graph.num_poses):
            v.insert(key(k), gtsam.Pose3(gtsam.Rot3(R[k]), t[k]))
    return v


def from_values(graph: PoseGraph, values: gtsam.Values) -> tuple[F64, F64]:
    """Stacked rotations and translations of the graph's nodes from ``values``."""
    n, d = graph.num_poses, graph.dim
    R = np.empty((n, d, d))
    t = np.empty((n, d))
    if d == 2:
        for k in range(n):
            p = values.atPose2(key(k))
            R[k] = p.rotation().matrix()
            t[k] = p.translation()
    else:
        for k in range(n):
            p = values.atPose3(key(k))
            R[k] = p.rotation().matrix()
            t[k] = p.translation()
    return R, t


def _measurement(graph: PoseGraph, e: int) -> gtsam.Pose2 | gtsam.Pose3:
    Rm, tm = graph.meas_rotations[e], graph.meas_translations[e]
    if graph.dim == 2:
        return gtsam.Pose2(float(tm[0]), float(tm[1]), float(np.arctan2(Rm[1, 0], Rm[0, 0])))
    return gtsam.Pose3(gtsam.Rot3(Rm), tm)


def between_graph(graph: PoseGraph, diagonal: bool = False) -> gtsam.NonlinearFactorGraph:
    """BetweenFactorPose2/3 for every edge (full information, or only its diagonal)."""
    fg = gtsam.NonlinearFactorGraph()
    cls = gtsam.BetweenFactorPose2 if graph.dim == 2 else gtsam.BetweenFactorPose3
    for e in range(graph.num_edges):
        info = graph.information[e]
        if diagonal:
            noise = gtsam.noiseModel.Diagonal.Precisions(np.diag(info).copy())
        else:
            noise = gtsam.noiseModel.Gaussian.Information(info)
        fg.add(cls(key(graph.edge_i[e]), key(graph.edge_j[e]), _measurement(graph, e), noise))
    return fg


def sesync_graph(graph: PoseGraph) -> gtsam.NonlinearFactorGraph:
    """``FrobeniusBetweenFactorPose2/3`` whose ``graph.error`` is SE-Sync's ``F`` exactly."""
    kappa, tau = sesync.weights(graph)
    d = graph.dim
    h = d + 1
    fg = gtsam.NonlinearFactorGraph()
    cls = gtsam.FrobeniusBetweenFactorPose2 if d == 2 else gtsam.FrobeniusBetweenFactorPose3
    # column-major vec of the (d+1)x(d+1) homogeneous matrix: rotation entries (row < d, col < d),
    # translation entries (row < d, col == d), constant zeros (row == d)
    rows = np.tile(np.arange(h), h)
    cols = np.repeat(np.arange(h), h)
    rot = (rows < d) & (cols < d)
    trans = (rows < d) & (cols == d)
    for e in range(graph.num_edges):
        prec = np.ones(h * h)
        prec[rot] = 2.0 * kappa[e]
        prec[trans] = 2.0 * tau[e]
        noise = gtsam.noiseModel.Diagonal.Precisions(prec)
        fg.add(cls(key(graph.edge_i[e]), key(graph.edge_j[e]), _measurement(graph, e), noise))
    return fg


def objective_graph(graph: PoseGraph, objective: str) -> gtsam.NonlinearFactorGraph:
    """The factor graph of ``objective`` (``geodesic`` or ``sesync``), without a gauge prior."""
    if objective == "geodesic":
        return between_graph(graph)
    if objective == "sesync":
        return sesync_graph(graph)
    raise InputError(f"unknown objective {objective!r} (choose from {', '.join(OBJECTIVES)})")


def _prior(graph: PoseGraph, values: gtsam.Values) -> gtsam.NonlinearFactor:
    if graph.dim == 2:
        return gtsam.PriorFactorPose2(key(0), values.atPose2(key(0)),
                                      gtsam.noiseModel.Isotropic.Sigma(3, PRIOR_SIGMA))
    return gtsam.PriorFactorPose3(key(0), values.atPose3(key(0)), gtsam.noiseModel.Isotropic.Sigma(6, PRIOR_SIGMA))


def indeterminate_near(exc: BaseException) -> str | None:
    """For GTSAM's ``IndeterminantLinearSystemException`` (a ``RuntimeError`` in Python): the
    variable it names (``"x472"``, or ``""`` when it names none); None for any other exception."""
    text = str(exc)
    if not isinstance(exc, RuntimeError) or "ndetermina" not in text:
        return None
    m = re.search(r"Symbol: (\w+)", text)
    return m.group(1) if m else ""


def chordal_poses(graph: PoseGraph) -> tuple[F64, F64]:
    """LAGO (2-D, on the diagonal of the information) or ``InitializePose3`` (3-D) poses.

    Raises GTSAM's ``RuntimeError`` when its linear solver gives up (see :func:`initialise`).
    """
    fg = between_graph(graph, diagonal=graph.dim == 2)
    anchor = gtsam.Values()
    if graph.dim == 2:
        anchor.insert(key(0), gtsam.Pose2())
        fg.add(_prior(graph, anchor))
        try:  # LAGO's default spanning tree is the odometric path (i, i+1): needs every such edge
            values = gtsam.lago.initialize(fg, True)
        except (IndexError, RuntimeError) as exc:
            if indeterminate_near(exc) is not None:
                raise
            values = gtsam.lago.initialize(fg, False)
    else:
        anchor.insert(key(0), gtsam.Pose3())
        fg.add(_prior(graph, anchor))
        values = gtsam.InitializePose3.initialize(fg)
    return from_values(graph, values)


def initialise(graph: PoseGraph, init: str, warn: Callable[[str], None] | None = None) -> tuple[F64, F64, str]:
    """Initial poses by ``init`` and the initialisation actually used: ``(R, t, used)``.

    ``chordal`` falls back to ``odometry`` (``used == "odometry"``, and ``warn`` gets one line)
    when GTSAM's sparse Cholesky declares the linear system of LAGO / InitializePose3
    indeterminate. That happens on well-posed graphs too: GTSAM refuses a frontal factor whose
    last two diagonal entries differ by 2^12 or more, which LAGO's second stage (translations and
    an orientation correction per pose, one 3x3 block each) produces when the translation
    precisions are ~1e6 times the rotation precisions (docs/posegraph.md).
    """
    if init != "chordal":
        return (*initial_poses(graph, init), init)
    try:
        R, t = chordal_poses(graph)
    except RuntimeError as exc:
        near = indeterminate_near(exc)
        if near is None:
            raise
        what = "LAGO" if graph.dim == 2 else "InitializePose3"
        if warn is not None:
            warn(f"chordal initialisation failed (GTSAM's {what}: indeterminate linear system"
                 f"{' near ' + near if near else ''}); starting from --init odometry instead")
        R, t = compose_spanning_tree(graph)
        return R, t, "odometry"
    return R, t, "chordal"


def initial_poses(graph: PoseGraph, init: str) -> tuple[F64, F64]:
    """Initial poses by ``init``: ``file``, ``odometry`` or ``chordal`` (LAGO / InitializePose3; no
    fallback here, see :func:`initialise`)."""
    if init == "file":
        if not graph.has_vertices:
            raise InputError("--init file needs a VERTEX line for every pose, and some (or all) are missing: "
                             "use --init odometry or chordal", graph.source or None)
        return graph.rotations.copy(), graph.translations.copy()
    if init == "odometry":
        return compose_spanning_tree(graph)
    if init == "chordal":
        return chordal_poses(graph)
    raise InputError(f"unknown initialisation {init!r} (choose from {', '.join(INITS)})")


@dataclass
class GtsamResult:
    """Poses at the end, GTSAM's final error of the chosen objective, iterations, seconds, and
    whether GTSAM's convergence test passed before the iteration cap."""

    rotations: F64
    translations: F64
    error: float
    iterations: int
    seconds: float
    converged: bool = True


def _optimizer(fg: gtsam.NonlinearFactorGraph, values: gtsam.Values, method: str, max_iterations: int,
               rel_tol: float, abs_tol: float) -> tuple[gtsam.NonlinearOptimizer, gtsam.NonlinearOptimizerParams]:
    if method == "lm":
        params: gtsam.NonlinearOptimizerParams = gtsam.LevenbergMarquardtParams()
    elif method == "gn":
        params = gtsam.GaussNewtonParams()
    elif method == "dogleg":
        params = gtsam.DoglegParams()
    else:
        raise InputError(f"unknown method {method!r} (choose from {', '.join(METHODS)})")
    params.setRelativeErrorTol(rel_tol)
    params.setAbsoluteErrorTol(abs_tol)
    params.setMaxIterations(max_iterations)
    if method == "lm":
        return gtsam.LevenbergMarquardtOptimizer(fg, values, params), params
    if method == "gn":
        return gtsam.GaussNewtonOptimizer(fg, values, params), params
    return gtsam.DoglegOptimizer(fg, values, params), params


def optimize(graph: PoseGraph, R0: F64, t0: F64, objective: str = "geodesic", method: str = "lm",
             max_iterations: int = 100, rel_tol: float = 1e-10, abs_tol: float = 1e-12) -> GtsamResult:
    """Run GTSAM's LM / Gauss-Newton / Dogleg on the objective's graph plus a gauge prior on ``x_0``.

    The loop is GTSAM's own (``NonlinearOptimizer::optimize``: ``iterate`` until
    ``checkConvergence`` or the cap), stepped from here so that ``converged`` is known.
    ``seconds`` is the optimiser's own time (graph construction excluded). GTSAM's
    indeterminate-system error (Gauss-Newton and Dogleg have no damping to fall back on) becomes
    one :class:`InputError` line.
    """
    fg = objective_graph(graph, objective)
    values = to_values(graph, R0, t0)
    fg.add(_prior(graph, values))
    opt, params = _optimizer(fg, values, method, max_iterations, rel_tol, abs_tol)
    start = time.perf_counter()
    current = opt.error()
    converged = current <= 0.0  # GTSAM's errorTol (0 by default): nothing to do
    try:
        while not converged and opt.iterations() < max_iterations and np.isfinite(current):
            opt.iterate()
            new = opt.error()
            converged = bool(gtsam.checkConvergence(params, current, new))
            current = new
    except RuntimeError as exc:
        near = indeterminate_near(exc)
        if near is None:
            raise
        raise InputError(f"GTSAM's {method} stopped at iteration {opt.iterations() + 1}: indeterminate linear "
                         f"system{' near ' + near if near else ''} (try --method lm)", graph.source or None) from None
    seconds = time.perf_counter() - start
    result = opt.values()
    R, t = from_values(graph, result)
    err = objective_graph(graph, objective).error(result)
    return GtsamResult(R, t, float(err), int(opt.iterations()), seconds, converged)
