"""Odometry-calibration residuals as GTSAM custom factors with analytic Jacobians.

Residual math only (no I/O). The calibration variable is a plain GTSAM vector (keyed by
:func:`calibration_key`):

* linear model: the 9-vector ``x`` of X's entries in row-major order, ``u' = X u``;
* diff-drive model: the 3-vector ``p = (k_L, k_R, k_b)`` of :mod:`gtvo.calibration.diff_drive`.

Factors:

* :func:`linear_calibration_factor` - one motion pair: ``e = u* - X u``, ``de/dx = -(I3 kron u^T)``.
* :func:`diff_drive_calibration_factor` - one motion pair: ``e = u* - f(u; p)``, ``de/dp = -df/dp``.
* :func:`calibrated_odometry_factor` - the joint-calibration odometry edge between Pose2 ``x_i``,
  ``x_j`` and the linear calibration ``x``: measurement ``Z = Pose2(X u)`` (the raw motion passed
  through the calibration), error ``e = Log(Z^-1 x_i^-1 x_j)`` as in ``BetweenFactorPose2``.

GTSAM's Pose2 tangent is ``(x, y, theta)`` with right perturbation ``T.retract(d) = T Exp(d)``.
With ``D = x_i^-1 x_j`` and ``E = Z^-1 D = Exp(e)``:

* ``de/dx_j = Jr^-1(e)``,
* ``de/dx_i = -Jr^-1(e) Ad(D^-1)``,
* ``de/dx  = -Jr^-1(e) Ad(E^-1) M (I3 kron u^T)`` with ``M = blockdiag(R(theta_Z)^T, 1)``: a change
  ``dv`` of the vector ``v = X u`` moves ``Z = Pose2(v)`` by ``Z Exp(M dv)`` to first order.

Note: from inside GTSAM's optimisers every Python factor call receives a copy of the whole
Values (see docs/odometry_calibration.md for what that costs here).
"""

from __future__ import annotations


import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.calibration.diff_drive import diff_drive_motion_scalar, wheel_arcs


def calibration_key(index: int = 0) -> int:
    """The key of the calibration variable: ``gtsam.symbol('c', index)``."""
    return gtsam.symbol("c", index)


def _kron_u(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """``I3 kron u^T`` (3x9): d(X u)/d vec_rowmajor(X)."""
    k = np.zeros((3, 9))
    k[0, 0:3] = u
    k[1, 3:6] = u
    k[2, 6:9] = u
    return k


def linear_calibration_error(x: ArrayLike, odom_motion: ArrayLike, reference_motion: ArrayLike
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``e = u* - X u`` and ``de/dx`` (3x9) for the row-major 9-vector ``x``."""
    u = np.asarray(odom_motion, dtype=np.float64).reshape(3)
    x = np.asarray(x, dtype=np.float64).reshape(3, 3)
    return np.asarray(reference_motion, dtype=np.float64).reshape(3) - x @ u, -_kron_u(u)


def linear_calibration_factor(key: int, odom_motion: ArrayLike, reference_motion: ArrayLike,
                              noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A unary factor on the 9-vector calibration: ``e = u* - X u`` for one motion pair."""
    u = np.array(odom_motion, dtype=np.float64).reshape(3)
    ref = np.array(reference_motion, dtype=np.float64).reshape(3)
    jac = -_kron_u(u)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> NDArray[np.float64]:
        x = values.atVector(this.keys()[0]).reshape(3, 3)
        if H is not None:
            H[0] = jac
        return ref - x @ u

    return gtsam.CustomFactor(noise, [key], error)


def diff_drive_calibration_factor(key: int, odom_motion: ArrayLike, reference_motion: ArrayLike,
                                  nominal_baseline: float, noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A unary factor on ``p = (k_L, k_R, k_b)``: ``e = u* - f(u; p)`` for one motion pair."""
    u = np.array(odom_motion, dtype=np.float64).reshape(1, 3)
    ref = np.array(reference_motion, dtype=np.float64).reshape(3)
    b0 = float(nominal_baseline)
    s_l, s_r = (float(w[0]) for w in wheel_arcs(u, b0))  # constant: computed once

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> NDArray[np.float64]:
        f, df = diff_drive_motion_scalar(values.atVector(this.keys()[0]), s_l, s_r, b0)
        if H is not None:
            H[0] = -df
        return ref - f

    return gtsam.CustomFactor(noise, [key], error)


def _vector_pose_jacobian(theta: float) -> NDArray[np.float64]:
    """``M``: ``Pose2(v + dv) = Pose2(v) Exp(M dv)`` to first order, ``M = blockdiag(R(theta)^T, 1)``."""
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def calibrated_odometry_error(pose_i: gtsam.Pose2, pose_j: gtsam.Pose2, x: ArrayLike, raw_motion: ArrayLike,
                              with_jacobians: bool = False):
    """``e = Log(Pose2(X u)^-1 x_i^-1 x_j)``; with ``with_jacobians`` also ``[de/dx_i, de/dx_j, de/dx]``."""
    u = np.asarray(raw_motion, dtype=np.float64).reshape(3)
    v = np.asarray(x, dtype=np.float64).reshape(3, 3) @ u
    z = gtsam.Pose2(v[0], v[1], v[2])
    d = pose_i.between(pose_j)
    big_e = z.between(d)
    e = gtsam.Pose2.Logmap(big_e)
    if not with_jacobians:
        return e
    jr_inv = gtsam.Pose2.LogmapDerivative(e)
    h_i = -jr_inv @ d.inverse().AdjointMap()
    h_j = jr_inv
    h_c = -jr_inv @ big_e.inverse().AdjointMap() @ _vector_pose_jacobian(v[2]) @ _kron_u(u)
    return e, [h_i, h_j, h_c]


def calibrated_odometry_factor(key_i: int, key_j: int, key_calibration: int, raw_motion: ArrayLike,
                               noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """Joint-calibration odometry edge on Pose2 ``x_i``, ``x_j`` and the linear 9-vector calibration."""
    u = np.array(raw_motion, dtype=np.float64).reshape(3)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> NDArray[np.float64]:
        k = this.keys()
        pi, pj, x = values.atPose2(k[0]), values.atPose2(k[1]), values.atVector(k[2])
        if H is None:
            return calibrated_odometry_error(pi, pj, x, u)
        e, jac = calibrated_odometry_error(pi, pj, x, u, with_jacobians=True)
        H[0], H[1], H[2] = jac
        return e

    return gtsam.CustomFactor(noise, [key_i, key_j, key_calibration], error)


