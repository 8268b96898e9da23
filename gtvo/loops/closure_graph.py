"""Loop closing on a keyframe pose graph: candidate loop edges, rejected or accepted by GNC.

Given the keyframe poses ``T_world_kf`` of a VO run (their consecutive relative poses become the
odometry edges) and candidate loop edges ``(i, j, T_i_j, information)`` from place recognition
(not part of this module), :func:`close_loops` adds every candidate as a ``BetweenFactorPose3``
and optimises with Graduated Non-Convexity (``gtsam.GncLMOptimizer``, truncated-least-squares
loss, inlier threshold at the 99 % chi-square quantile of 6 degrees of freedom, set explicitly:
GTSAM 4.3's default, not a promise of every version). Odometry edges are declared known
inliers; a candidate whose final GNC weight is below 0.5 is rejected, so one false loop cannot
bend the map; a last LM solve on odometry plus the accepted loops gives the returned poses.
``method="huber"`` / ``"cauchy"`` instead wrap the loop edges in a robust kernel and reject by
the chi-square test of the final residual.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.config.sections.loops import CHI2_6DOF_99
from gtvo.core.keys import pose_key
from gtvo.errors import InputError

F64 = NDArray[np.float64]
METHODS = ("gnc", "huber", "cauchy")
#: GNC's truncated least squares treats a loop as an inlier while its chi-square is below this
#: quantile (``GncOptimizer.setInlierCostThresholdsAtProbability``): 16.8 for a 6-dof loop.
GNC_INLIER_PROBABILITY = 0.99


@dataclass
class LoopEdge:
    """A loop edge: the measured ``T_i_j = T_world_i^-1 T_world_j`` (4x4) with its 6x6 information
    (GTSAM order ``[rot, trans]``). Any object with these four fields works too (e.g. a
    :class:`gtvo.loops.LoopCandidate`, once its indices are keyframe positions)."""

    i: int
    j: int
    T_i_j: F64
    information: F64


@dataclass
class LoopClosureResult:
    """Optimised keyframe poses (4x4 ``T_world_kf``), per-candidate acceptance and weight, and the
    final error of odometry plus accepted loops."""

    poses: F64
    accepted: NDArray[np.bool_]
    weights: F64
    error: float


def _pose3(T: F64) -> gtsam.Pose3:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"a pose must be a finite 4x4 matrix, got shape {T.shape}")
    return gtsam.Pose3(gtsam.Rot3(T[:3, :3]), T[:3, 3])


def close_loops(poses: Sequence[F64] | F64, candidates: Sequence[LoopEdge],
                odometry_information: F64 | None = None, method: str = "gnc") -> LoopClosureResult:
    """Optimise the keyframe graph ``odometry + candidate loops``; see the module docstring.

    ``poses``: ``(n, 4, 4)`` keyframe poses ``T_world_kf`` (the odometry edges are their
    consecutive relative poses, with ``odometry_information``: one 6x6 for all edges or one per
    edge, ``(n - 1, 6, 6)``; default identity x 1e4).
    """
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or len(P) < 2:
        raise InputError(f"keyframe poses must be (n>=2, 4, 4), got {P.shape}")
    if method not in METHODS:
        raise InputError(f"unknown loop-closure method {method!r} (choose from {', '.join(METHODS)})")
    n = len(P)
    Xs = [_pose3(T) for T in P]
    info_odo = np.eye(6) * 1e4 if odometry_information is None else np.asarray(odometry_information, float)
    if info_odo.shape == (6, 6):
        info_odo = np.broadcast_to(info_odo, (n - 1, 6, 6))
    if info_odo.shape != (n - 1, 6, 6) or not np.all(np.isfinite(info_odo)):
        raise InputError(f"odometry information must be a finite 6x6 or ({n - 1}, 6, 6), got {info_odo.shape}")
    key = pose_key
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(key(0), Xs[0], gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for k in range(n - 1):
        odo_noise = gtsam.noiseModel.Gaussian.Information(np.array(info_odo[k]))
        graph.add(gtsam.BetweenFactorPose3(key(k), key(k + 1), Xs[k].between(Xs[k + 1]), odo_noise))
    first_loop = graph.size()
    for c in candidates:
        if not (0 <= c.i < n and 0 <= c.j < n) or c.i == c.j:
            raise InputError(f"loop candidate ({c.i}, {c.j}) does not connect two of the {n} keyframes")
        noise = gtsam.noiseModel.Gaussian.Information(np.asarray(c.information, float))
        if method == "huber":
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345), noise)
        elif method == "cauchy":
            noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(1.0), noise)
        graph.add(gtsam.BetweenFactorPose3(key(c.i), key(c.j), _pose3(c.T_i_j), noise))
    initial = gtsam.Values()
    for k, X in enumerate(Xs):
        initial.insert(key(k), X)
    m = len(candidates)
    if method == "gnc":
        params = gtsam.GncLMParams(gtsam.LevenbergMarquardtParams())
        params.setKnownInliers(list(range(first_loop)))
        opt = gtsam.GncLMOptimizer(graph, initial, params)
        opt.setInlierCostThresholdsAtProbability(GNC_INLIER_PROBABILITY)
        result = opt.optimize()
        weights = np.asarray(opt.getWeights(), float)[first_loop:]
        accepted = weights > 0.5
    else:
        result = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams()).optimize()
        chi2 = np.empty(m)
        for e, c in enumerate(candidates):
            f = gtsam.BetweenFactorPose3(key(c.i), key(c.j), _pose3(c.T_i_j),
                                         gtsam.noiseModel.Gaussian.Information(np.asarray(c.information, float)))
            chi2[e] = 2.0 * f.error(result)
        accepted = chi2 < CHI2_6DOF_99
        weights = accepted.astype(float)
    # final solve on the graph that keeps only the accepted loops, so a rejected loop has no
    # influence at all (GNC leaves it a weight of ~1e-5, which still moves poses by centimetres)
    kept = gtsam.NonlinearFactorGraph()
    for k in range(first_loop):
        kept.add(graph.at(k))
    for e, c in enumerate(candidates):
        if accepted[e]:
            kept.add(gtsam.BetweenFactorPose3(key(c.i), key(c.j), _pose3(c.T_i_j),
                                              gtsam.noiseModel.Gaussian.Information(np.asarray(c.information, float))))
    result = gtsam.LevenbergMarquardtOptimizer(kept, result, gtsam.LevenbergMarquardtParams()).optimize()
    out = np.stack([result.atPose3(key(k)).matrix() for k in range(n)])
    return LoopClosureResult(out, accepted, weights, float(kept.error(result)))
