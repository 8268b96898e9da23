"""The notes' linear odometry calibration: ``u'_i = X u_i`` with the 3x3 matrix X by least squares.

Pure numpy, no I/O. Notation (the notes on estimation and odometry calibration, section 3):

* ``u_i``  raw (biased) odometry motion ``(dx, dy, dtheta)``; ``u*_i`` the reference motion.
* ``x``    the 9-vector of X's entries in row-major order ``(x11, x12, x13, x21, ..., x33)``.
* error    ``e_i(x) = u*_i - X u_i``.
* Jacobian ``J_i = de_i/dx = -[[u_i^T, 0, 0], [0, u_i^T, 0], [0, 0, u_i^T]]`` (3x9, i.e. ``-I3 kron u_i^T``).
* normal equations ``H dx = -b`` with ``H = sum J_i^T J_i``, ``b = sum J_i^T e_i`` (identity information);
  the error is linear in x, so one step from any ``x0`` lands on the minimum: ``x = x0 - H^-1 b``.
* residual variance ``sigma^2 = sum |e_i|^2 / (3N - 9)`` (unbiased, one common sigma for all three
  components) and parameter covariance ``Cov(x) = sigma^2 H^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gtvo.wheel_calibration.motions import MOTION_COMPONENTS, as_motions
from gtvo.wheel_calibration.observability import (DEFAULT_RCOND, Observability, analyse_normal_matrix,
                                            raise_if_unobservable)
from gtvo.errors import InputError

#: Names of X's columns, for messages about unobservable parameters.
LINEAR_COLUMN_NAMES: tuple[str, str, str] = tuple(f"X[.,{j}] ({c} column)" for j, c in enumerate(MOTION_COMPONENTS))
#: Names of the 9 parameters in row-major order.
LINEAR_PARAMETER_NAMES: tuple[str, ...] = tuple(f"X[{r},{c}]" for r in range(3) for c in range(3))


@dataclass(frozen=True)
class ResidualStatistics:
    """Statistics of the residuals ``e_i`` (N, 3) of a fit with ``n_parameters`` parameters."""

    n_motions: int
    n_parameters: int
    rss: float                      # sum of squared residuals
    dof: int                        # 3N - n_parameters
    sigma2: float                   # rss / dof
    rms: NDArray[np.float64]        # per component (dx, dy, dtheta)
    mean: NDArray[np.float64]
    std: NDArray[np.float64]
    max_abs: NDArray[np.float64]

    @classmethod
    def from_residuals(cls, residuals: NDArray[np.float64], n_parameters: int) -> "ResidualStatistics":
        """Statistics of an (N, 3) residual array."""
        e = np.asarray(residuals, dtype=np.float64)
        n = e.shape[0]
        rss = float(np.sum(e * e))
        dof = 3 * n - n_parameters
        return cls(n_motions=n, n_parameters=n_parameters, rss=rss, dof=dof,
                   sigma2=rss / dof if dof > 0 else float("nan"),
                   rms=np.sqrt(np.mean(e * e, axis=0)), mean=e.mean(axis=0), std=e.std(axis=0),
                   max_abs=np.abs(e).max(axis=0))

    def to_dict(self) -> dict:
        """JSON-friendly dictionary."""
        return {"n_motions": self.n_motions, "n_parameters": self.n_parameters, "rss": self.rss,
                "dof": self.dof, "sigma2": self.sigma2, "sigma": float(np.sqrt(self.sigma2)),
                "rms": dict(zip(MOTION_COMPONENTS, self.rms.tolist())),
                "mean": dict(zip(MOTION_COMPONENTS, self.mean.tolist())),
                "std": dict(zip(MOTION_COMPONENTS, self.std.tolist())),
                "max_abs": dict(zip(MOTION_COMPONENTS, self.max_abs.tolist()))}


@dataclass(frozen=True)
class LinearCalibration:
    """Result of the linear calibration ``u' = X u``."""

    X: NDArray[np.float64]                  # 3x3
    covariance: NDArray[np.float64]         # 9x9 over row-major vec(X): sigma^2 H^-1
    residuals: ResidualStatistics
    observability: Observability            # SVD of H
    solver: str = "handrolled"

    @property
    def standard_errors(self) -> NDArray[np.float64]:
        """3x3 standard deviations of X's entries (sqrt of the covariance diagonal)."""
        return np.sqrt(np.diag(self.covariance)).reshape(3, 3)

    def apply(self, motions: ArrayLike) -> NDArray[np.float64]:
        """Calibrated motions ``u' = X u`` of an (N, 3) array."""
        return apply_linear(self.X, motions)

    def to_dict(self) -> dict:
        """JSON-friendly dictionary (``model``, ``X``, ``covariance``, residual statistics...)."""
        return {"model": "linear", "solver": self.solver, "X": self.X.tolist(),
                "det_X": float(np.linalg.det(self.X)),
                "standard_errors": self.standard_errors.tolist(),
                "covariance": self.covariance.tolist(),
                "covariance_note": "sigma^2 H^-1 over row-major vec(X), sigma^2 = RSS / (3N - 9)",
                "residuals": self.residuals.to_dict(),
                "condition_number": self.observability.condition_number}


def apply_linear(X: ArrayLike, motions: ArrayLike) -> NDArray[np.float64]:
    """``u'_i = X u_i`` for every row of ``motions``."""
    return as_motions(motions) @ np.asarray(X, dtype=np.float64).reshape(3, 3).T


def linear_errors(x: ArrayLike, odom: NDArray[np.float64], reference: NDArray[np.float64]) -> NDArray[np.float64]:
    """``e_i = u*_i - X u_i`` (N, 3) for the 9-vector ``x``."""
    return reference - odom @ np.asarray(x, dtype=np.float64).reshape(3, 3).T


def linear_jacobians(odom: NDArray[np.float64]) -> NDArray[np.float64]:
    """``J_i = de_i/dx = -(I3 kron u_i^T)``, stacked (N, 3, 9)."""
    n = odom.shape[0]
    j = np.zeros((n, 3, 9))
    for r in range(3):
        j[:, r, 3 * r:3 * r + 3] = -odom
    return j


def normal_equations(x: ArrayLike, odom: NDArray[np.float64],
                     reference: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``H = sum J_i^T J_i`` (9x9) and ``b = sum J_i^T e_i`` (9) at ``x``."""
    j = linear_jacobians(odom)
    e = linear_errors(x, odom, reference)
    return np.einsum("nij,nik->jk", j, j), np.einsum("nij,ni->j", j, e)


def check_linear_observability(odom: NDArray[np.float64], rcond: float = DEFAULT_RCOND,
                               where: str = "linear calibration") -> Observability:
    """Raise InputError naming X's undetermined columns (or column combinations) if the motions cannot fix X.

    ``H = I3 kron (U^T U)``, so X is determined exactly when the 3x3 ``U^T U`` has full rank; a null
    vector ``v`` of it means ``X v`` (a column, or a combination of columns) is unobservable in every row.
    """
    n = odom.shape[0]
    if n < 4:
        raise InputError(f"{where}: too few motions: {n} given, the linear model needs at least 4 "
                         "(9 parameters, 3 residuals per motion, and a residual degree of freedom for the covariance)")
    obs = analyse_normal_matrix(odom.T @ odom, rcond)
    reasons = [f"all {c} are zero" for j, c in enumerate(MOTION_COMPONENTS) if not np.any(odom[:, j])]
    if not reasons and not obs.observable:
        reasons = [f"the {n} motions span only {obs.rank} of the 3 motion directions"]
    raise_if_unobservable(obs, LINEAR_COLUMN_NAMES, reasons, what=where)
    return obs


def fit_linear(odom: ArrayLike, reference: ArrayLike, rcond: float = DEFAULT_RCOND) -> LinearCalibration:
    """Least-squares X with ``reference ~ X odom`` by the notes' normal equations (closed form).

    Raises InputError for NaN rows, mismatched lengths, too few motions, or motions that leave
    part of X undetermined (naming it).
    """
    u = as_motions(odom, "odometry motions")
    ref = as_motions(reference, "reference motions")
    if u.shape != ref.shape:
        raise InputError(f"odometry has {u.shape[0]} motions but the reference has {ref.shape[0]}")
    check_linear_observability(u, rcond)
    x0 = np.eye(3).ravel()
    h, b = normal_equations(x0, u, ref)
    obs = analyse_normal_matrix(h, rcond)
    c, low = _cho_factor(h)
    x = x0 - _cho_solve(c, low, b)
    # one more pass: the problem is linear, this only removes round-off of the first step
    _, b1 = normal_equations(x, u, ref)
    x = x - _cho_solve(c, low, b1)
    stats = ResidualStatistics.from_residuals(linear_errors(x, u, ref), 9)
    cov = stats.sigma2 * _cho_solve(c, low, np.eye(9))
    return LinearCalibration(X=x.reshape(3, 3), covariance=0.5 * (cov + cov.T), residuals=stats,
                             observability=obs)


def _cho_factor(h: NDArray[np.float64]):
    from scipy.linalg import cho_factor  # noqa: PLC0415
    return cho_factor(h)


def _cho_solve(c, low, rhs):
    from scipy.linalg import cho_solve  # noqa: PLC0415
    return cho_solve((c, low), rhs)
