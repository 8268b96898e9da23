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

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.wheel_calibration.linear import ResidualStatistics
from gtvo.wheel_calibration.motions import as_motions
from gtvo.wheel_calibration.observability import DEFAULT_RCOND, Observability, analyse_normal_matrix, raise_if_unobservable
from gtvo.errors import InputError
from factors.odometry_calibration import arc_coefficients, wheel_arcs

#: Parameter names, in the order of the parameter vector p.
DIFF_DRIVE_PARAMETER_NAMES: tuple[str, str, str] = ("left wheel scale k_L", "right wheel scale k_R",
                                                    "baseline scale k_b")



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
