"""Differential-drive kinematic calibration: wheel scale factors and baseline scale.

Pure numpy, no I/O. The model (see docs/odometry_calibration.md):

* The raw odometry ``u = (dx, dy, dtheta)`` was computed by the robot from its wheel arc lengths with
  *nominal* parameters (wheel radii r_L0, r_R0 and baseline b0) and the constant-curvature (arc)
  motion model ``dx = s A(dtheta)``, ``dy = s B(dtheta)`` with ``A(t) = sin t / t`` and
  ``B(t) = (1 - cos t) / t``, ``s`` the arc length of the centre of the axle.
* Recover the nominal arc length ``s = (dx cos(t/2) + dy sin(t/2)) / A(t/2)`` (exact for an arc;
  for a raw motion that is not an exact arc it is the projection onto the chord direction) and the
  nominal wheel arcs ``s_L = s - b0 t/2``, ``s_R = s + b0 t/2`` (``t = dtheta``).
* The true parameters are ``r_L = k_L r_L0``, ``r_R = k_R r_R0``, ``b = k_b b0``, so the true wheel arcs
  are ``k_L s_L``, ``k_R s_R`` and the calibrated motion is
  ``s' = (k_R s_R + k_L s_L) / 2``, ``t' = (k_R s_R - k_L s_L) / (k_b b0)``,
  ``u' = f(u; p) = (s' A(t'), s' B(t'), t')`` with ``p = (k_L, k_R, k_b)``.
* error ``e_i = u*_i - f(u_i; p)``, solved by Gauss-Newton (``H dp = -b`` per iteration), covariance
  ``sigma^2 H^-1`` with ``sigma^2 = RSS / (3N - 3)``.

The split of the result between k_L, k_R and k_b depends on the nominal baseline b0 (it converts
heading change into wheel arcs): pass the robot's nominal baseline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.calibration.linear import ResidualStatistics
from gtvo.calibration.motions import as_motions
from gtvo.calibration.observability import DEFAULT_RCOND, Observability, analyse_normal_matrix, raise_if_unobservable
from gtvo.errors import InputError

#: Parameter names, in the order of the parameter vector p.
DIFF_DRIVE_PARAMETER_NAMES: tuple[str, str, str] = ("left wheel scale k_L", "right wheel scale k_R",
                                                    "baseline scale k_b")

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


def diff_drive_motions_from_arcs(s_left: NDArray[np.float64], s_right: NDArray[np.float64],
                                 baseline: float) -> NDArray[np.float64]:
    """Arc-model motions ``(dx, dy, dtheta)`` of wheel arcs ``s_L, s_R`` on an axle of length ``baseline``."""
    s = 0.5 * (s_left + s_right)
    t = (s_right - s_left) / baseline
    a, b, _, _ = arc_coefficients(t)
    return np.column_stack([s * a, s * b, t])


def apply_diff_drive(params: ArrayLike, odom: ArrayLike, nominal_baseline: float = 1.0,
                     with_jacobian: bool = False):
    """Calibrated motions ``f(u; p)`` (N, 3); with ``with_jacobian`` also ``df/dp`` (N, 3, 3)."""
    k_l, k_r, k_b = np.asarray(params, dtype=np.float64).reshape(3)
    u = as_motions(odom)
    s_l, s_r = wheel_arcs(u, nominal_baseline)
    s = 0.5 * (k_r * s_r + k_l * s_l)
    bb = k_b * nominal_baseline
    t = (k_r * s_r - k_l * s_l) / bb
    a, b, da, db = arc_coefficients(t)
    f = np.column_stack([s * a, s * b, t])
    if not with_jacobian:
        return f
    ds = np.column_stack([0.5 * s_l, 0.5 * s_r, np.zeros_like(s)])          # ds'/dp  (N, 3)
    dt = np.column_stack([-s_l / bb, s_r / bb, -t / k_b])                    # dt'/dp  (N, 3)
    df_ds = np.column_stack([a, b, np.zeros_like(a)])                        # (N, 3)
    df_dt = np.column_stack([s * da, s * db, np.ones_like(a)])
    jac = df_ds[:, :, None] * ds[:, None, :] + df_dt[:, :, None] * dt[:, None, :]
    return f, jac


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


@dataclass(frozen=True)
class DiffDriveCalibration:
    """Result of the differential-drive calibration."""

    params: NDArray[np.float64]             # (k_L, k_R, k_b)
    nominal_baseline: float
    covariance: NDArray[np.float64]         # 3x3, sigma^2 H^-1
    residuals: ResidualStatistics
    observability: Observability
    iterations: int
    solver: str = "handrolled"

    @property
    def baseline(self) -> float:
        """Calibrated baseline ``k_b * b0`` (m, in the unit of the nominal baseline)."""
        return float(self.params[2] * self.nominal_baseline)

    def apply(self, motions: ArrayLike) -> NDArray[np.float64]:
        """Calibrated motions of an (N, 3) raw-motion array."""
        return apply_diff_drive(self.params, motions, self.nominal_baseline)

    def to_dict(self) -> dict:
        """JSON-friendly dictionary (``model``, the scales, covariance, residual statistics...)."""
        k_l, k_r, k_b = self.params.tolist()
        return {"model": "diff-drive", "solver": self.solver, "left_wheel_scale": k_l, "right_wheel_scale": k_r,
                "baseline_scale": k_b, "nominal_baseline": self.nominal_baseline, "baseline": self.baseline,
                "standard_errors": np.sqrt(np.diag(self.covariance)).tolist(),
                "covariance": self.covariance.tolist(),
                "covariance_note": "sigma^2 H^-1 over (k_L, k_R, k_b), sigma^2 = RSS / (3N - 3)",
                "residuals": self.residuals.to_dict(), "iterations": self.iterations,
                "condition_number": self.observability.condition_number}


def diff_drive_normal_equations(params: ArrayLike, odom: NDArray[np.float64], reference: NDArray[np.float64],
                                nominal_baseline: float):
    """``(H, b, e)``: normal matrix, gradient ``sum J_i^T e_i`` and errors ``e_i = u*_i - f(u_i; p)``."""
    f, df = apply_diff_drive(params, odom, nominal_baseline, with_jacobian=True)
    e = reference - f
    j = -df
    return np.einsum("nij,nik->jk", j, j), np.einsum("nij,ni->j", j, e), e


def check_diff_drive_observability(h: NDArray[np.float64], odom: NDArray[np.float64],
                                   rcond: float = DEFAULT_RCOND, where: str = "diff-drive calibration") -> Observability:
    """InputError naming the wheel/baseline parameters the motions cannot determine."""
    obs = analyse_normal_matrix(h, rcond)
    reasons = []
    if not np.any(odom[:, 2]):
        reasons.append("all dtheta are zero (straight-line motion only)")
    if not np.any(odom[:, :2]):
        reasons.append("all dx and dy are zero (turning on the spot only)")
    raise_if_unobservable(obs, DIFF_DRIVE_PARAMETER_NAMES, reasons, what=where)
    return obs


def fit_diff_drive(odom: ArrayLike, reference: ArrayLike, nominal_baseline: float = 1.0,
                   initial: ArrayLike = (1.0, 1.0, 1.0), max_iterations: int = 50,
                   tolerance: float = 1e-12, rcond: float = DEFAULT_RCOND) -> DiffDriveCalibration:
    """Gauss-Newton fit of ``p = (k_L, k_R, k_b)`` with ``reference ~ f(odom; p)``.

    Stops when the step is below ``tolerance * (1 + |p|)``. Raises InputError for NaN rows, too few
    motions, a non-positive nominal baseline, unobservable parameters (named) or divergence.
    """
    u = as_motions(odom, "odometry motions")
    ref = as_motions(reference, "reference motions")
    if u.shape != ref.shape:
        raise InputError(f"odometry has {u.shape[0]} motions but the reference has {ref.shape[0]}")
    if not (np.isfinite(nominal_baseline) and nominal_baseline > 0):
        raise InputError(f"nominal baseline must be a positive length, got {nominal_baseline}")
    if u.shape[0] < 2:
        raise InputError(f"diff-drive calibration: too few motions: {u.shape[0]} given, at least 2 needed")
    p = np.asarray(initial, dtype=np.float64).reshape(3).copy()
    h, b, _ = diff_drive_normal_equations(p, u, ref, nominal_baseline)
    check_diff_drive_observability(h, u, rcond)
    it = 0
    for it in range(1, max_iterations + 1):
        dp = -np.linalg.solve(h, b)
        p = p + dp
        if not np.all(np.isfinite(p)) or p[2] <= 0:
            raise InputError(f"diff-drive calibration diverged (parameters {p.tolist()})")
        h, b, _ = diff_drive_normal_equations(p, u, ref, nominal_baseline)
        if np.linalg.norm(dp) < tolerance * (1 + np.linalg.norm(p)):
            break
    obs = check_diff_drive_observability(h, u, rcond)
    _, _, e = diff_drive_normal_equations(p, u, ref, nominal_baseline)
    stats = ResidualStatistics.from_residuals(e, 3)
    cov = stats.sigma2 * np.linalg.inv(h)
    return DiffDriveCalibration(params=p, nominal_baseline=float(nominal_baseline), covariance=0.5 * (cov + cov.T),
                                residuals=stats, observability=obs, iterations=it)
