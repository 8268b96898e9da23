"""The planar constant-acceleration motion model as native linear-Gaussian GTSAM factors.

Residual math only (no I/O, no pipeline state); the model and its names are those of
:mod:`gtvo.motion.model`. Each state ``x_t = [X, dX, Z, dZ, theta, dtheta]`` is a 6-vector
variable (key :func:`gtvo.core.keys.motion_state_key`, ``v<t>``). The model is linear, so the factors are
``gtsam.JacobianFactor`` s with error ``sum_j A_j x_j - b`` whitened by a noise model, and the
graph is a ``gtsam.GaussianFactorGraph`` whose solution is the exact posterior mean.

Process factor. ``x_t - A x_{t-1} = G a`` with ``a ~ N(0, diag(k^2))``. Its covariance
``R_t = G diag(k^2) G^T`` is singular (rank 3), so it has no information form. Per axis, with
``e = x_t - A x_{t-1} = (e_p, e_v)`` the same statement is

    e_v / T = a ~ N(0, k^2)           (soft row, sigma k)
    e_p - (T/2) e_v = 0               (hard row: since e_p = T^2/2 a and e_v = T a)

so the factor is ``W (x_t - A x_{t-1}) = 0`` with the invertible row map ``W`` (per axis
``[[0, 1/T], [1, -T/2]]``) and a ``noiseModel.Constrained`` with sigmas ``(k, 0)`` per axis.
GTSAM eliminates constrained rows exactly (weighted Gram-Schmidt in its QR).
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from numpy.typing import NDArray

from gtvo.errors import InputError

FloatArray = NDArray[np.float64]

#: State layout.
STATE_DIM = 6
X_INDEX, DX_INDEX, Z_INDEX, DZ_INDEX, THETA_INDEX, DTHETA_INDEX = range(6)

#: ``C``: the measurement ``(X, Z, theta)`` selects state rows 0, 2 and 4.
POSE_MEASUREMENT_MATRIX: FloatArray = np.zeros((3, STATE_DIM))
POSE_MEASUREMENT_MATRIX[0, X_INDEX] = 1.0
POSE_MEASUREMENT_MATRIX[1, Z_INDEX] = 1.0
POSE_MEASUREMENT_MATRIX[2, THETA_INDEX] = 1.0
POSE_MEASUREMENT_MATRIX.setflags(write=False)


def check_dt(dt: float) -> float:
    """``dt`` as a float, or InputError unless it is finite and > 0."""
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise InputError(f"motion model time step must be finite and > 0, got {dt!r}")
    return dt



def transition_matrix(dt: float) -> FloatArray:
    """``A``: the 6x6 constant-velocity transition over ``dt`` seconds (block ``[[1, dt], [0, 1]]``)."""
    dt = check_dt(dt)
    A = np.eye(STATE_DIM)
    A[X_INDEX, DX_INDEX] = A[Z_INDEX, DZ_INDEX] = A[THETA_INDEX, DTHETA_INDEX] = dt
    return A


#: Penalty weight GTSAM uses for constrained rows in nonlinear error evaluation (its default).
CONSTRAINT_MU = 1000.0


def process_row_map(dt: float) -> np.ndarray:
    """``W`` (6x6): the rows ``[e_v / T, e_p - (T/2) e_v]`` per axis of ``e = x_t - A x_{t-1}``."""
    W = np.zeros((STATE_DIM, STATE_DIM))
    for axis in range(3):
        p, v = 2 * axis, 2 * axis + 1
        W[p, v] = 1.0 / dt          # soft row: the acceleration a
        W[v, p] = 1.0               # hard row: e_p - T/2 e_v
        W[v, v] = -0.5 * dt
    return W


def process_factor(key_prev: int, key_next: int, dt: float, accel_sigmas: ArrayLike) -> gtsam.JacobianFactor:
    """``x_next = A(dt) x_prev + G a``, ``a ~ N(0, diag(accel_sigmas^2))``, as a JacobianFactor."""
    A = transition_matrix(dt)
    W = process_row_map(dt)
    k = np.asarray(accel_sigmas, dtype=np.float64).reshape(3)
    sigmas = np.zeros(STATE_DIM)
    sigmas[0::2] = k                # soft rows; hard rows keep sigma 0
    model = gtsam.noiseModel.Constrained.MixedSigmas(CONSTRAINT_MU, sigmas)
    return gtsam.JacobianFactor(key_prev, -W @ A, key_next, W, np.zeros(STATE_DIM), model)


def pose_measurement_factor(key: int, z: ArrayLike, sigmas: ArrayLike) -> gtsam.JacobianFactor:
    """``C x = z + n``, ``n ~ N(0, diag(sigmas^2))``: a measured planar pose ``(X, Z, theta)``."""
    return gtsam.JacobianFactor(key, np.array(POSE_MEASUREMENT_MATRIX), np.asarray(z, dtype=np.float64).reshape(3),
                                gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=np.float64).reshape(3)))


def state_prior_factor(key: int, mean: ArrayLike, cov: ArrayLike) -> gtsam.JacobianFactor:
    """``x ~ N(mean, cov)`` on one state, pre-whitened: ``L^-1 x = L^-1 mean`` with ``cov = L L^T``.

    (The wrapped ``JacobianFactor`` constructors take only diagonal noise models.)
    """
    L = np.linalg.cholesky(np.asarray(cov, dtype=np.float64))
    L_inv = np.linalg.solve(L, np.eye(STATE_DIM))
    return gtsam.JacobianFactor(key, L_inv, L_inv @ np.asarray(mean, dtype=np.float64).reshape(STATE_DIM),
                                gtsam.noiseModel.Unit.Create(STATE_DIM))
