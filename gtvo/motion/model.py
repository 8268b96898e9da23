"""Planar constant-acceleration motion model: Kalman filter and Rauch-Tung-Striebel smoother.

Pure math, no I/O. The state is ``x = [X, dX, Z, dZ, theta, dtheta]`` (metres, m/s, radians,
rad/s): the camera's position on the ground plane (the world x-z plane; camera y is down) and its
yaw ``theta`` about the y axis, each with its rate. Between two frames ``T`` seconds apart each
axis moves as

    p_t = p_{t-1} + T v_{t-1} + T^2/2 a,      v_t = v_{t-1} + T a,      a ~ N(0, k^2)

(the acceleration is white, piecewise constant over the interval), so

    x_t = A x_{t-1} + G a,   A = blockdiag([[1, T], [0, 1]] x 3),   G = blockdiag([T^2/2, T]^T x 3)

and the process noise is ``R_t = G diag(k1^2, k2^2, k3^2) G^T`` whose 2x2 block per axis is
``[[T^4/4, T^3/2], [T^3/2, T^2]] k^2`` (:func:`process_noise`). The notes' last entry reads
``T^2 k2^2``; the block pattern (and this derivation) gives ``T^2 k3^2`` (docs/motion_model.md).

Each 2x2 block has rank 1 (its determinant is ``T^6/4 - T^6/4 = 0``): ``R_t`` is singular. The
filter does not mind (``A S A^T + R_t`` stays positive definite); the factor-graph twin
(:mod:`factors.motion`) turns the null directions into hard constraints.

Measurements are planar poses ``z = (X, Z, theta) = C x`` with ``C`` selecting rows 0, 2, 4
(:data:`POSE_MEASUREMENT_MATRIX`) and covariance ``Q``. The update is

    K = S C^T (C S C^T + Q)^-1,   mu = mu_bar + K wrap(z - C mu_bar),   S' = (I - K C) S

which for ``C = I`` is exactly the notes' Algorithm 2 (``K = S (S + Q)^-1``). Angle rows of the
innovation are wrapped to (-pi, pi] and the state's theta is kept in (-pi, pi].

Planar pose of a camera (:func:`planar_pose_from_T_world_cam`): ``theta`` is the heading of the
optical axis in the x-z plane, ``theta = atan2(R[0, 2], R[2, 2])``: 0 looks along world +z,
positive theta turns the optical axis towards +x (a right-handed rotation about +y, which points
down: seen from above the camera turns clockwise, i.e. to the right).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.motion import POSE_MEASUREMENT_MATRIX, STATE_DIM, THETA_INDEX, X_INDEX, Z_INDEX, check_dt, transition_matrix
from gtvo.config.sections.motion import INITIAL_RATE_SIGMAS, MotionNoiseConfig
from gtvo.config.sections.motion import check_sigmas as _check_sigmas
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]

def wrap_angle(angle: ArrayLike) -> FloatArray | float:
    """Wrap angles (radians) to the half-open interval (-pi, pi]."""
    a = np.asarray(angle, dtype=np.float64)
    wrapped = np.pi - np.mod(np.pi - a, 2.0 * np.pi)
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def noise_gain(dt: float) -> FloatArray:
    """``G`` (6x3): how an acceleration ``a = (aX, aZ, atheta)`` held over ``dt`` enters the state."""
    dt = check_dt(dt)
    G = np.zeros((STATE_DIM, 3))
    for axis in range(3):
        G[2 * axis, axis] = 0.5 * dt * dt
        G[2 * axis + 1, axis] = dt
    return G


def process_noise(dt: float, k1: float, k2: float, k3: float) -> FloatArray:
    """``R_t`` of the notes: ``G diag(k1^2, k2^2, k3^2) G^T``.

    Block per axis ``[[T^4/4, T^3/2], [T^3/2, T^2]] k^2`` with ``k1`` for X, ``k2`` for Z and
    ``k3`` for theta (the last diagonal entry is ``T^2 k3^2``; the notes' ``T^2 k2^2`` is a typo).
    ``k`` are the standard deviations of the accelerations (m/s^2, m/s^2, rad/s^2).
    """
    k = _check_sigmas("accelerations sigmas (k1, k2, k3)", (k1, k2, k3), 3, allow_zero=True)
    G = noise_gain(dt)
    return (G * (k * k)) @ G.T


def _angle_rows(C: FloatArray) -> NDArray[np.int64]:
    """Rows of ``C`` that measure theta alone (their innovation is an angle difference)."""
    e = np.zeros(STATE_DIM)
    e[THETA_INDEX] = 1.0
    return np.flatnonzero(np.all(C == e, axis=1))


def predict(mean: ArrayLike, cov: ArrayLike, dt: float, accel_sigmas: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Algorithm 2, lines 2-3: ``mu_bar = A mu``, ``S_bar = A S A^T + R_t``; theta wrapped."""
    A = transition_matrix(dt)
    k = _check_sigmas("accelerations sigmas (k1, k2, k3)", accel_sigmas, 3, allow_zero=True)
    mean_bar = A @ np.asarray(mean, dtype=np.float64)
    mean_bar[THETA_INDEX] = wrap_angle(mean_bar[THETA_INDEX])
    cov_bar = A @ np.asarray(cov, dtype=np.float64) @ A.T + process_noise(dt, *k)
    return mean_bar, 0.5 * (cov_bar + cov_bar.T)


def update(mean_bar: ArrayLike, cov_bar: ArrayLike, z: ArrayLike, Q: ArrayLike,
           C: ArrayLike = POSE_MEASUREMENT_MATRIX) -> tuple[FloatArray, FloatArray]:
    """Algorithm 2, lines 4-6, with a measurement matrix ``C``.

    ``K = S C^T (C S C^T + Q)^-1``, ``mu = mu_bar + K wrap(z - C mu_bar)``, ``S' = (I - K C) S``
    (symmetrised). Innovation rows that measure theta alone are wrapped to (-pi, pi]. With
    ``C = I`` this is the notes' ``K = S (S + Q)^-1`` and ``S' = (E - K) S``.
    """
    C = np.asarray(C, dtype=np.float64)
    mean_bar = np.asarray(mean_bar, dtype=np.float64)
    cov_bar = np.asarray(cov_bar, dtype=np.float64)
    z = np.asarray(z, dtype=np.float64).reshape(-1)
    Q = np.asarray(Q, dtype=np.float64)
    if z.shape != (C.shape[0],) or not np.all(np.isfinite(z)):
        raise InputError(f"measurement must be {C.shape[0]} finite numbers, got {z.tolist()!r}")
    innovation = z - C @ mean_bar
    rows = _angle_rows(C)
    innovation[rows] = wrap_angle(innovation[rows])
    S_innov = C @ cov_bar @ C.T + Q
    # K = cov_bar C^T S_innov^-1, solved rather than inverted (S_innov is symmetric).
    K = np.linalg.solve(S_innov, C @ cov_bar).T
    mean = mean_bar + K @ innovation
    mean[THETA_INDEX] = wrap_angle(mean[THETA_INDEX])
    cov = (np.eye(STATE_DIM) - K @ C) @ cov_bar
    return mean, 0.5 * (cov + cov.T)


@dataclass(frozen=True)
class FilterResult:
    """Everything a forward pass produced (what the smoother needs).

    ``means[t]``, ``covs[t]``: filtered state after measurement ``t``; ``predicted_means[t]``,
    ``predicted_covs[t]``: before it (for ``t = 0``: the prior); ``dts[t]``: time from state
    ``t-1`` to ``t`` (``dts[0]`` is unused, 0).
    """

    means: FloatArray
    covs: FloatArray
    predicted_means: FloatArray
    predicted_covs: FloatArray
    dts: FloatArray


def _check_prior(mean: ArrayLike, cov: ArrayLike) -> tuple[FloatArray, FloatArray]:
    mean = np.asarray(mean, dtype=np.float64).reshape(-1)
    cov = np.asarray(cov, dtype=np.float64)
    if mean.shape != (STATE_DIM,) or not np.all(np.isfinite(mean)):
        raise InputError(f"prior mean must be 6 finite numbers, got {mean.tolist()!r}")
    if cov.shape != (STATE_DIM, STATE_DIM) or not np.all(np.isfinite(cov)):
        raise InputError(f"prior covariance must be a finite 6x6 matrix, got shape {cov.shape}")
    try:
        np.linalg.cholesky(0.5 * (cov + cov.T))
    except np.linalg.LinAlgError:
        raise InputError("prior covariance must be symmetric positive definite") from None
    return mean, cov


def filter_sequence(measurements: ArrayLike, times: ArrayLike, prior_mean: ArrayLike, prior_cov: ArrayLike,
                    noise: MotionNoiseConfig = MotionNoiseConfig()) -> FilterResult:
    """Run the filter over ``N`` pose measurements ``(X, Z, theta)`` taken at ``times`` (seconds).

    The prior ``(prior_mean, prior_cov)`` is on the state at ``times[0]``; measurement 0 updates it,
    then each later measurement follows a prediction over ``times[t] - times[t-1]``.
    """
    z = np.asarray(measurements, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    if z.ndim != 2 or z.shape[1] != 3 or z.shape[0] == 0:
        raise InputError(f"measurements must be an (N, 3) array of (X, Z, theta) with N >= 1, got shape {z.shape}")
    if t.shape != (z.shape[0],):
        raise InputError(f"times must have one entry per measurement ({z.shape[0]}), got shape {t.shape}")
    bad = np.flatnonzero(~np.all(np.isfinite(z), axis=1))
    if bad.size:
        raise InputError(f"measurement {int(bad[0])} is not finite: {z[bad[0]].tolist()!r}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise InputError("times must be finite and strictly increasing")
    mean, cov = _check_prior(prior_mean, prior_cov)
    n = z.shape[0]
    means = np.empty((n, STATE_DIM))
    covs = np.empty((n, STATE_DIM, STATE_DIM))
    pmeans = np.empty((n, STATE_DIM))
    pcovs = np.empty((n, STATE_DIM, STATE_DIM))
    dts = np.concatenate([[0.0], np.diff(t)])
    Q = noise.Q
    for i in range(n):
        if i > 0:
            mean, cov = predict(mean, cov, dts[i], noise.accel_sigmas)
        pmeans[i], pcovs[i] = mean, cov
        mean, cov = update(mean, cov, z[i], Q)
        means[i], covs[i] = mean, cov
    return FilterResult(means, covs, pmeans, pcovs, dts)


def rts_smooth(result: FilterResult) -> tuple[FloatArray, FloatArray]:
    """Rauch-Tung-Striebel smoother over a forward pass: smoothed means (N, 6) and covariances.

    Backwards from the last state: ``J_t = S_t A^T S_bar_{t+1}^-1``,
    ``mu^s_t = mu_t + J_t wrap(mu^s_{t+1} - mu_bar_{t+1})``,
    ``S^s_t = S_t + J_t (S^s_{t+1} - S_bar_{t+1}) J_t^T`` (theta differences wrapped).
    """
    n = result.means.shape[0]
    means = result.means.copy()
    covs = result.covs.copy()
    for i in range(n - 2, -1, -1):
        A = transition_matrix(result.dts[i + 1])
        P_pred = result.predicted_covs[i + 1]
        J = np.linalg.solve(P_pred, A @ result.covs[i]).T  # S_t A^T P_pred^-1 (P_pred symmetric)
        diff = means[i + 1] - result.predicted_means[i + 1]
        diff[THETA_INDEX] = wrap_angle(diff[THETA_INDEX])
        means[i] = result.means[i] + J @ diff
        means[i, THETA_INDEX] = wrap_angle(means[i, THETA_INDEX])
        c = result.covs[i] + J @ (covs[i + 1] - P_pred) @ J.T
        covs[i] = 0.5 * (c + c.T)
    return means, covs


class ConstantAccelerationFilter:
    """Stateful filter for a tracker: feed it poses, ask it where the camera will be.

    Usage in the VO (the tracker's initial guess)::

        f = ConstantAccelerationFilter(MotionNoiseConfig(...))
        f.initialize(planar_pose_from_T_world_cam(T0))
        ...
        X, Z, theta = f.predict_pose(dt)                          # guess for the next frame
        T_guess = T_world_cam_from_planar_pose(X, Z, theta, reference=T_prev)
        ...                                                         # track, get T_new
        f.step(planar_pose_from_T_world_cam(T_new), dt)             # predict + update
    """

    def __init__(self, noise: MotionNoiseConfig = MotionNoiseConfig(),
                 initial_rate_sigmas: tuple[float, float, float] = INITIAL_RATE_SIGMAS) -> None:
        self.noise = noise
        self.initial_rate_sigmas = tuple(_check_sigmas("initial_rate_sigmas", initial_rate_sigmas, 3))
        self._mean: FloatArray | None = None
        self._cov: FloatArray | None = None

    @property
    def initialized(self) -> bool:
        """Whether :meth:`initialize` has been called."""
        return self._mean is not None

    @property
    def mean(self) -> FloatArray:
        """Current state mean ``[X, dX, Z, dZ, theta, dtheta]`` (a copy)."""
        self._require()
        return self._mean.copy()  # type: ignore[union-attr]

    @property
    def cov(self) -> FloatArray:
        """Current 6x6 state covariance (a copy)."""
        self._require()
        return self._cov.copy()  # type: ignore[union-attr]

    def _require(self) -> None:
        if self._mean is None:
            raise InputError("ConstantAccelerationFilter used before initialize()")

    def initialize(self, pose: ArrayLike, rates: ArrayLike = (0.0, 0.0, 0.0)) -> None:
        """Start at a measured pose ``(X, Z, theta)`` with rates ``(dX, dZ, dtheta)``.

        The initial covariance is ``Q`` on the pose rows and ``initial_rate_sigmas^2`` on the rates.
        """
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        r = np.asarray(rates, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or r.shape != (3,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(r))):
            raise InputError(f"initial pose and rates must be 3 finite numbers each, got {p.tolist()!r}, {r.tolist()!r}")
        mean = np.array([p[0], r[0], p[1], r[1], wrap_angle(p[2]), r[2]])
        var = np.empty(STATE_DIM)
        var[0::2] = np.square(self.noise.measurement_sigmas)
        var[1::2] = np.square(self.initial_rate_sigmas)
        self._mean, self._cov = mean, np.diag(var)

    def predict(self, dt: float) -> tuple[FloatArray, FloatArray]:
        """Advance the state by ``dt`` seconds without a measurement; returns (mean, cov)."""
        self._require()
        self._mean, self._cov = predict(self._mean, self._cov, dt, self.noise.accel_sigmas)  # type: ignore[arg-type]
        return self.mean, self.cov

    def update(self, pose: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Fuse a measured pose ``(X, Z, theta)``; returns (mean, cov)."""
        self._require()
        self._mean, self._cov = update(self._mean, self._cov, pose, self.noise.Q)  # type: ignore[arg-type]
        return self.mean, self.cov

    def step(self, pose: ArrayLike, dt: float) -> tuple[FloatArray, FloatArray]:
        """:meth:`predict` over ``dt`` then :meth:`update` with ``pose``."""
        self.predict(dt)
        return self.update(pose)

    def predict_pose(self, dt: float) -> tuple[float, float, float]:
        """The pose ``(X, Z, theta)`` expected ``dt`` seconds ahead; the filter is not changed."""
        self._require()
        m = transition_matrix(dt) @ self._mean
        return float(m[X_INDEX]), float(m[Z_INDEX]), float(wrap_angle(m[THETA_INDEX]))


def _yaw_rotation(theta: float) -> FloatArray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def planar_pose_from_T_world_cam(T_world_cam: ArrayLike) -> tuple[float, float, float]:
    """The planar measurement ``(X, Z, theta)`` of a 4x4 ``T_world_cam`` (camera y down).

    ``X, Z``: the camera centre's world x and z; ``theta = atan2(R[0, 2], R[2, 2])``: the heading
    of the optical axis (third column of R) in the x-z plane, 0 along +z, positive towards +x.
    """
    T = np.asarray(T_world_cam, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if np.hypot(R[0, 2], R[2, 2]) < 1e-9:
        raise InputError("T_world_cam looks straight up or down: its heading in the x-z plane is undefined")
    return float(T[0, 3]), float(T[2, 3]), float(np.arctan2(R[0, 2], R[2, 2]))


def T_world_cam_from_planar_pose(X: float, Z: float, theta: float,
                                 reference: ArrayLike | None = None) -> FloatArray:
    """A 4x4 ``T_world_cam`` at planar pose ``(X, Z, theta)``.

    Without ``reference``: rotation ``R_y(theta) = [[c, 0, s], [0, 1, 0], [-s, 0, c]]`` and height
    ``y = 0``. With a ``reference`` ``T_world_cam`` (e.g. the previous frame), its height y and its
    pitch/roll are kept and only the heading is replaced: ``R = R_y(theta - theta_ref) R_ref``.
    In both cases :func:`planar_pose_from_T_world_cam` of the result returns ``(X, Z, theta)``.
    """
    T = np.eye(4)
    if reference is None:
        T[:3, :3] = _yaw_rotation(theta)
    else:
        ref = np.asarray(reference, dtype=np.float64)
        _, _, theta_ref = planar_pose_from_T_world_cam(ref)
        T[:3, :3] = _yaw_rotation(theta - theta_ref) @ ref[:3, :3]
        T[1, 3] = ref[1, 3]
    T[0, 3], T[2, 3] = X, Z
    return T
