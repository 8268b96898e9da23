"""Pose covariances of the window's keyframes at the optimum (docs/window.md, "Pose covariances").

Each keyframe's 6x6 covariance is in GTSAM's tangent order ``[rotation, translation]`` with the
right perturbation ``T = T_hat * Exp(xi)``: the covariance of ``xi`` in the keyframe's own camera
frame. It is the pose block of the inverse of the window's reduced system (poses and affines,
depths Schur-eliminated inside each host) at the optimum, with the gauge prior or the
marginalisation prior in it: the uncertainty relative to the world frame fixed by the first
keyframe, under the window's linearised past.

* GTSAM path: ``gtsam.Marginals`` of the window's graph at the optimum (:func:`marginals_of_graph`);
* hand-rolled path: the inverse of the undamped reduced Hessian the LM assembles (:func:`marginals_of_hessian`);
* fixed-lag path: ``IncrementalFixedLagSmoother.marginalCovariance`` (iSAM2's Bayes tree).
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from gtvo.core.keys import pose_key
from gtvo.core.timing import timed

FloatArray = NDArray[np.float64]

def symmetric(P: FloatArray) -> FloatArray:
    """``(P + P^T) / 2`` (round-off of an inversion removed)."""
    P = np.asarray(P, dtype=float)
    return 0.5 * (P + P.T)


def undetermined(indices: Sequence[int]) -> dict[int, FloatArray]:
    """All-NaN covariances: the window's system did not determine them (singular at the optimum)."""
    return {int(i): np.full((6, 6), np.nan) for i in indices}


@timed("covariances", absorb=True)  # gtsam.Marginals' linearisation included
def marginals_of_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                       indices: Sequence[int]) -> dict[int, FloatArray]:
    """``gtsam.Marginals(graph, values)``: the 6x6 pose covariance of every keyframe index in ``indices``
    (all NaN when GTSAM finds the system indeterminate)."""
    try:
        marginals = gtsam.Marginals(graph, values)
        return {int(i): symmetric(marginals.marginalCovariance(pose_key(i))) for i in indices}
    except RuntimeError:  # gtsam.IndeterminantLinearSystemException
        return undetermined(indices)


@timed("covariances", absorb=True)
def marginals_of_hessian(H: FloatArray, indices: Sequence[int], block: int = 8) -> dict[int, FloatArray]:
    """The pose blocks of ``H^-1`` for a state of ``block`` entries per keyframe (pose first).

    ``H`` is the reduced (undamped) Gauss-Newton Hessian at the optimum, symmetric positive definite
    when the gauge is fixed (gauge or marginal prior); all NaN when it is not (Cholesky fails).
    """
    H = symmetric(H)
    # scale to unit diagonal first: the gauge prior (1e12) sits beside photometric curvatures (1e5)
    d = np.diag(H)
    if not np.all(np.isfinite(H)) or np.any(d <= 0):
        return undetermined(indices)
    s = 1.0 / np.sqrt(d)
    try:
        L = np.linalg.cholesky(H * s[:, None] * s[None, :])
    except np.linalg.LinAlgError:
        return undetermined(indices)
    Linv = np.linalg.inv(L)
    C = (Linv.T @ Linv) * s[:, None] * s[None, :]
    return {int(i): symmetric(C[block * k:block * k + 6, block * k:block * k + 6]) for k, i in enumerate(indices)}


@timed("covariances", absorb=True)
def marginals_of_smoother(smoother: gtsam.IncrementalFixedLagSmoother, indices: Sequence[int]
                          ) -> dict[int, FloatArray]:
    """The smoother's (iSAM2) marginal covariance of every keyframe pose in ``indices``."""
    return {int(i): symmetric(smoother.marginalCovariance(pose_key(i))) for i in indices}
