"""Smoothness priors: between neighbouring inverse depths, and on the motion of three poses.

* :class:`InverseDepthSmoothnessFactor` (with :func:`edge_aware_weight`): neighbouring points of
  one keyframe have similar inverse depths, except across image edges.
* :class:`MotionSmoothnessFactor` (equally spaced frames) and :class:`ConstantVelocityFactor`
  (irregular times, the window's keyframes): the body-frame motion changes little from one step
  to the next. Jacobians for GTSAM's right perturbations; derivations: docs/factors.md §6.
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from factors.gtsam_factors import PythonFactor, robust_unit_noise
from gtvo.errors import InputError


def edge_aware_weight(intensity_i: ArrayLike, intensity_j: ArrayLike, edge_scale: float = 10.0) -> np.ndarray:
    """Smoothness weight between two neighbouring points, small across strong image edges.

    ``w = exp(-((I_i - I_j) / edge_scale)^2)``: 1 on a flat patch, ``exp(-1)`` at an intensity
    step of ``edge_scale`` (8-bit units), vanishing across strong edges where depth may jump.
    """
    diff = (np.asarray(intensity_i, dtype=float) - np.asarray(intensity_j, dtype=float)) / float(edge_scale)
    return np.exp(-diff * diff)


class InverseDepthSmoothnessFactor(PythonFactor):
    """Smoothness between the inverse depths of two neighbouring points of one keyframe.

    Error ``sqrt(weight) * (d_j - d_i) / sigma_d`` (a scalar); ``dError/dd_i = -sqrt(weight)/sigma_d``,
    ``dError/dd_j = +sqrt(weight)/sigma_d``. Use :func:`edge_aware_weight` for ``weight``.

    Args:
        key_i, key_j: inverse-depth keys.
        sigma_d: expected inverse-depth difference of neighbours (1/m).
        weight: edge-aware down-weighting in [0, 1].
        huber_k: Huber threshold on the whitened difference (None: quadratic), so real depth
            discontinuities that the edge weight missed are not smoothed away.
    """

    def __init__(self, key_i: int, key_j: int, sigma_d: float = 0.01, weight: float = 1.0,
                 huber_k: float | None = 1.345) -> None:
        if not (np.isfinite(sigma_d) and sigma_d > 0):
            raise InputError(f"sigma_d must be positive, got {sigma_d!r}")
        if not (np.isfinite(weight) and weight >= 0):
            raise InputError(f"smoothness weight must be >= 0, got {weight!r}")
        self.scale = np.sqrt(float(weight)) / float(sigma_d)
        self.key_i, self.key_j = key_i, key_j
        super().__init__(robust_unit_noise(1, huber_k), [key_i, key_j])

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        di = values.atDouble(self.key_i)
        dj = values.atDouble(self.key_j)
        if H is not None:
            H[0] = np.array([[-self.scale]])
            H[1] = np.array([[self.scale]])
        return np.array([self.scale * (dj - di)])


def motion_smoothness_error(T_prev: gtsam.Pose3, T_cur: gtsam.Pose3, T_next: gtsam.Pose3,
                            jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Constant-velocity residual ``e = Log(D1^-1 D2)``, ``D1 = T_prev^-1 T_cur``, ``D2 = T_cur^-1 T_next``.

    With ``E = D1^-1 D2`` and ``Jr^-1 = gtsam.Pose3.LogmapDerivative(E)`` (right perturbations):
    ``de/dxi_prev = Jr^-1 Ad(D2^-1)``, ``de/dxi_cur = -Jr^-1 (Ad(E^-1) + Ad(D2^-1))``,
    ``de/dxi_next = Jr^-1`` (derivation: docs/factors.md).
    """
    D1 = T_prev.between(T_cur)
    D2 = T_cur.between(T_next)
    E = D1.inverse().compose(D2)
    e = gtsam.Pose3.Logmap(E)
    if not jacobians:
        return e, None
    Jri = gtsam.Pose3.LogmapDerivative(E)
    AdD2i = D2.inverse().AdjointMap()
    AdEi = E.inverse().AdjointMap()
    return e, [Jri @ AdD2i, -Jri @ (AdEi + AdD2i), Jri]


class MotionSmoothnessFactor(PythonFactor):
    """Constant-velocity prior on three consecutive poses ``x_{k-1}, x_k, x_{k+1}``.

    Error ``Log((x_{k-1}^-1 x_k)^-1 (x_k^-1 x_{k+1}))`` (6, [rotation, translation]): zero when
    the relative motion repeats. Noise: sigmas of the change of the per-frame motion, e.g.
    ``rotation_sigma`` radians and ``translation_sigma`` metres per frame^2.

    Args:
        key_prev, key_cur, key_next: Pose3 keys.
        rotation_sigma, translation_sigma: standard deviations (scalars or 3-vectors).
    """

    def __init__(self, key_prev: int, key_cur: int, key_next: int, rotation_sigma: float | Sequence[float] = 0.01,
                 translation_sigma: float | Sequence[float] = 0.05) -> None:
        rs = np.broadcast_to(np.asarray(rotation_sigma, dtype=float), (3,))
        ts = np.broadcast_to(np.asarray(translation_sigma, dtype=float), (3,))
        sig = np.concatenate([rs, ts])
        if not (np.all(np.isfinite(sig)) and np.all(sig > 0)):
            raise InputError(f"motion smoothness sigmas must be positive, got {sig.tolist()}")
        self.pose_keys = (key_prev, key_cur, key_next)
        super().__init__(gtsam.noiseModel.Diagonal.Sigmas(sig), [key_prev, key_cur, key_next])

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        Ts = [values.atPose3(k) for k in self.pose_keys]
        e, J = motion_smoothness_error(*Ts, jacobians=H is not None)
        if H is not None:
            H[0], H[1], H[2] = J
        return e


def velocity_change_error(T_prev: gtsam.Pose3, T_cur: gtsam.Pose3, T_next: gtsam.Pose3, dt_prev: float,
                          dt_next: float, jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Change of the body-frame velocity over three poses at irregular times.

    ``e = Log(D2) / dt_next - Log(D1) / dt_prev`` ([rad/s, m/s], GTSAM's [rotation, translation]
    order), ``D1 = T_prev^-1 T_cur``, ``D2 = T_cur^-1 T_next``; zero for a constant body twist
    ``T(t) = T_0 Exp(t xi)`` whatever the time steps. With ``Jr^-1(D) = Pose3.LogmapDerivative(D)``
    (right perturbations): ``de/dxi_prev = Jr^-1(D1) Ad(D1^-1) / dt_prev``,
    ``de/dxi_cur = -Jr^-1(D1) / dt_prev - Jr^-1(D2) Ad(D2^-1) / dt_next``,
    ``de/dxi_next = Jr^-1(D2) / dt_next`` (derivation: docs/factors.md §6).
    """
    D1 = T_prev.between(T_cur)
    D2 = T_cur.between(T_next)
    e = gtsam.Pose3.Logmap(D2) / dt_next - gtsam.Pose3.Logmap(D1) / dt_prev
    if not jacobians:
        return e, None
    J1 = gtsam.Pose3.LogmapDerivative(D1)
    J2 = gtsam.Pose3.LogmapDerivative(D2)
    J2Ad = J2 @ D2.inverse().AdjointMap()
    return e, [J1 @ D1.inverse().AdjointMap() / dt_prev, -J1 / dt_prev - J2Ad / dt_next, J2 / dt_next]


class ConstantVelocityFactor(PythonFactor):
    """Constant-velocity prior on three poses taken at irregular times (e.g. keyframes).

    Error :func:`velocity_change_error` (6, rad/s and m/s) with sigmas ``acceleration_sigma * tau``,
    ``tau = (dt_prev + dt_next) / 2`` the time between the two velocity estimates: the sigmas are
    those of the acceleration (rad/s^2, m/s^2). :class:`MotionSmoothnessFactor` is the same prior
    for equally spaced frames in per-frame units.

    Args:
        key_prev, key_cur, key_next: Pose3 keys, in time order.
        dt_prev, dt_next: times (s) from prev to cur and from cur to next (> 0).
        angular_acceleration_sigma: rad/s^2 (scalar or 3-vector, body axes).
        linear_acceleration_sigma: m/s^2 (scalar or 3-vector, body axes).
    """

    def __init__(self, key_prev: int, key_cur: int, key_next: int, dt_prev: float, dt_next: float,
                 angular_acceleration_sigma: float | Sequence[float] = 1.0,
                 linear_acceleration_sigma: float | Sequence[float] = 2.0) -> None:
        self.dt = (float(dt_prev), float(dt_next))
        if not all(np.isfinite(t) and t > 0 for t in self.dt):
            raise InputError(f"ConstantVelocityFactor needs positive time steps, got {dt_prev!r}, {dt_next!r}")
        acc = np.concatenate([np.broadcast_to(np.asarray(angular_acceleration_sigma, dtype=float), (3,)),
                              np.broadcast_to(np.asarray(linear_acceleration_sigma, dtype=float), (3,))])
        if not (np.all(np.isfinite(acc)) and np.all(acc > 0)):
            raise InputError(f"acceleration sigmas must be positive, got {acc.tolist()}")
        self.sigmas = acc * 0.5 * (self.dt[0] + self.dt[1])
        self.pose_keys = (key_prev, key_cur, key_next)
        super().__init__(gtsam.noiseModel.Diagonal.Sigmas(self.sigmas), [key_prev, key_cur, key_next])

    def whitened(self, T_prev: gtsam.Pose3, T_cur: gtsam.Pose3, T_next: gtsam.Pose3
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
        """The whitened error ``e / sigmas`` and its three Jacobians at these poses (for solvers
        that assemble their own normal equations); the cost is ``|e / sigmas|^2 / 2``."""
        e, J = velocity_change_error(T_prev, T_cur, T_next, *self.dt, jacobians=True)
        assert J is not None
        return e / self.sigmas, [Ji / self.sigmas[:, None] for Ji in J]

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        Ts = [values.atPose3(k) for k in self.pose_keys]
        e, J = velocity_change_error(*Ts, *self.dt, jacobians=H is not None)
        if H is not None:
            H[0], H[1], H[2] = J
        return e
