"""Odometry-calibration residuals as GTSAM custom factors with analytic Jacobians.

Residual math only (no I/O). The calibration variable is a plain GTSAM vector (keyed by
:func:`gtvo.core.keys.calibration_key`):

* linear model: the 9-vector ``x`` of X's entries in row-major order, ``u' = X u``;
* diff-drive model: the 3-vector ``p = (k_L, k_R, k_b)`` of :mod:`gtvo.wheel_calibration.diff_drive`.

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

import math
from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray



_SERIES_BELOW = 0.05  # |t| below which A, B and their derivatives use their Taylor series


def arc_coefficients(t: ArrayLike) -> tuple[NDArray[np.float64], ...]:
    """``A(t) = sin t/t``, ``B(t) = (1-cos t)/t`` and their derivatives ``A'(t)``, ``B'(t)`` (series near 0)."""
    t = np.asarray(t, dtype=np.float64)
    small = np.abs(t) < _SERIES_BELOW
    ts = np.where(small, 1.0, t)  # safe divisor
    t2 = t * t
    a = np.where(small, 1 - t2 / 6 * (1 - t2 / 20 * (1 - t2 / 42 * (1 - t2 / 72))), np.sin(ts) / ts)
    b = np.where(small, t / 2 * (1 - t2 / 12 * (1 - t2 / 30 * (1 - t2 / 56 * (1 - t2 / 90)))), (1 - np.cos(ts)) / ts)
    da = np.where(small, -t / 3 + t * t2 / 30 - t * t2 * t2 / 840 + t * t2 ** 3 / 45360,
                  (ts * np.cos(ts) - np.sin(ts)) / (ts * ts))
    db = np.where(small, 0.5 - t2 / 8 + t2 * t2 / 144 - t2 ** 3 / 5760 + t2 ** 4 / 403200,
                  (ts * np.sin(ts) - (1 - np.cos(ts))) / (ts * ts))
    return a, b, da, db


def wheel_arcs(odom: NDArray[np.float64], nominal_baseline: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Nominal left and right wheel arc lengths ``(s_L, s_R)`` that produced the raw motions."""
    t = odom[:, 2]
    ah = arc_coefficients(t / 2)[0]
    s = (odom[:, 0] * np.cos(t / 2) + odom[:, 1] * np.sin(t / 2)) / ah
    return s - nominal_baseline * t / 2, s + nominal_baseline * t / 2


def _arc_scalar(t: float) -> tuple[float, float, float, float]:
    """:func:`arc_coefficients` for one float (no numpy overhead: used per factor call)."""
    if abs(t) < _SERIES_BELOW:
        t2 = t * t
        return (1 - t2 / 6 * (1 - t2 / 20 * (1 - t2 / 42 * (1 - t2 / 72))),
                t / 2 * (1 - t2 / 12 * (1 - t2 / 30 * (1 - t2 / 56 * (1 - t2 / 90)))),
                -t / 3 + t * t2 / 30 - t * t2 * t2 / 840 + t * t2 ** 3 / 45360,
                0.5 - t2 / 8 + t2 * t2 / 144 - t2 ** 3 / 5760 + t2 ** 4 / 403200)
    c, s = math.cos(t), math.sin(t)
    return s / t, (1 - c) / t, (t * c - s) / (t * t), (t * s - (1 - c)) / (t * t)


def diff_drive_motion_scalar(params: Sequence[float], s_left: float, s_right: float, nominal_baseline: float
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``f(u; p)`` (3) and ``df/dp`` (3x3) for one motion given by its nominal wheel arcs (see :func:`wheel_arcs`).

    The same math as :func:`apply_diff_drive`, written for one motion so that a per-motion GTSAM
    factor does not pay numpy's per-call overhead.
    """
    k_l, k_r, k_b = float(params[0]), float(params[1]), float(params[2])
    s = 0.5 * (k_r * s_right + k_l * s_left)
    bb = k_b * nominal_baseline
    t = (k_r * s_right - k_l * s_left) / bb
    a, b, da, db = _arc_scalar(t)
    f = np.array([s * a, s * b, t])
    ds = np.array([0.5 * s_left, 0.5 * s_right, 0.0])
    dt = np.array([-s_left / bb, s_right / bb, -t / k_b])
    jac = np.outer([a, b, 0.0], ds) + np.outer([s * da, s * db, 1.0], dt)
    return f, jac


def kron_motion(u: NDArray[np.float64]) -> NDArray[np.float64]:
    """``I3 kron u^T`` (3x9): d(X u)/d vec_rowmajor(X)."""
    k = np.zeros((3, 9))
    k[0, 0:3] = u
    k[1, 3:6] = u
    k[2, 6:9] = u
    return k


def linear_calibration_factor(key: int, odom_motion: ArrayLike, reference_motion: ArrayLike,
                              noise: gtsam.noiseModel.Base) -> gtsam.CustomFactor:
    """A unary factor on the 9-vector calibration: ``e = u* - X u`` for one motion pair."""
    u = np.array(odom_motion, dtype=np.float64).reshape(3)
    ref = np.array(reference_motion, dtype=np.float64).reshape(3)
    jac = -kron_motion(u)

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
    h_c = -jr_inv @ big_e.inverse().AdjointMap() @ _vector_pose_jacobian(v[2]) @ kron_motion(u)
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


