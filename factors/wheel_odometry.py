"""The wheel-odometry factor of the window: raw wheel motion, calibrated, against the camera poses.

Between two keyframes ``i``, ``j`` (camera poses ``T_i``, ``T_j``: ``T_world_cam``, Pose3) the
base of the robot moved by

    D = B_i^-1 B_j,   B = T T_base_cam^-1   (T_world_base),   i.e.   D = T_bc (T_i^-1 T_j) T_bc^-1

with ``T_bc = T_base_cam`` (fixed, from the configuration; REP 103 base: x forward, y left, z up).
The wheels measured the raw planar motion ``u = (dx, dy, dtheta)`` over the same interval (in the
base frame at ``t_i``: :mod:`gtvo.wheel_calibration.motions`); the calibration ``c`` maps it to
the true motion ``v = f(u; c)`` (:func:`calibrated_motion`):

* ``linear``: ``c`` the 9 entries of the notes' X row-major, ``v = X u``;
* ``diff_drive``: ``c = (k_L, k_R, k_b)`` (:mod:`factors.odometry_calibration`'s arc model with the
  nominal track width ``b0``).

The wheels' motion lifted to 3-D is ``Z = Pose3(Rz(v_theta), (v_x, v_y, 0))``: the base stays on
its plane (no roll, pitch or height change). The error is the 6-vector

    e = Log(Z^-1 D)     (GTSAM's [omega, v] order: roll, pitch, yaw, x, y, z of the base)

as GTSAM's ``BetweenFactorPose3`` of the measurement ``Z``. Its rows are the planar residual
(yaw, x, y: the calibrated wheel motion against the cameras') and the planar-motion terms (roll,
pitch, height change of the base), each with its own sigma (:func:`wheel_step_sigmas`). With
``E = Z^-1 D`` and ``Jr^-1 = Pose3.LogmapDerivative(e)`` (right perturbations ``T Exp(xi)``):

* ``de/dxi_j = Jr^-1 Ad(T_bc)``,
* ``de/dxi_i = -Jr^-1 Ad(D^-1) Ad(T_bc)``,
* ``de/dc = -Jr^-1 Ad(E^-1) M(v_theta) df/dc``, with ``M`` (6x3) the planar tangent
  (``Z(v + dv) = Z(v) Exp(M dv)`` to first order: ``omega_z = dtheta``, ``(v_x, v_y) = R(theta)^T (dx, dy)``).

Derivation and tests: docs/factors.md ("Wheel odometry"), tests/test_wheel_factor.py.
"""

from __future__ import annotations

from typing import Literal, Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

from factors.gtsam_factors import PythonFactor
from factors.odometry_calibration import kron_motion, diff_drive_motion_scalar, wheel_arcs
from gtvo.errors import InputError

FloatArray = NDArray[np.float64]
WheelModel = Literal["linear", "diff_drive"]

#: Number of calibration parameters of each model.
CALIBRATION_SIZE: dict[str, int] = {"linear": 9, "diff_drive": 3}
#: Names of the diff-drive parameters (report.json's keys), in the order of the vector.
DIFF_DRIVE_NAMES: tuple[str, str, str] = ("left_wheel_scale", "right_wheel_scale", "track_width_scale")


def nominal_calibration(model: str) -> FloatArray:
    """The calibration that changes nothing: X = I (row-major 9-vector) or ``k_L = k_R = k_b = 1``."""
    if model == "linear":
        return np.eye(3).ravel()
    if model == "diff_drive":
        return np.ones(3)
    raise InputError(f"unknown wheel model {model!r}: use 'linear' or 'diff_drive'")


def calibrated_motion(model: str, params: ArrayLike, raw_motion: ArrayLike, nominal_baseline: float = 1.0
                      ) -> tuple[FloatArray, FloatArray]:
    """``v = f(u; c)`` (3) and ``df/dc`` (3 x P) of one raw wheel motion ``u``."""
    u = np.asarray(raw_motion, dtype=np.float64).reshape(3)
    c = np.asarray(params, dtype=np.float64).reshape(-1)
    if model == "linear":
        return c.reshape(3, 3) @ u, kron_motion(u)
    if model == "diff_drive":
        s_l, s_r = (float(w[0]) for w in wheel_arcs(u.reshape(1, 3), nominal_baseline))
        return diff_drive_motion_scalar(c, s_l, s_r, nominal_baseline)
    raise InputError(f"unknown wheel model {model!r}: use 'linear' or 'diff_drive'")


def planar_pose(v: ArrayLike) -> gtsam.Pose3:
    """The planar motion ``(x, y, theta)`` as a Pose3 on the base's plane (no roll, pitch, height)."""
    x, y, t = (float(a) for a in np.asarray(v, dtype=np.float64).reshape(3))
    return gtsam.Pose3(gtsam.Rot3.Rz(t), gtsam.Point3(x, y, 0.0))


def planar_tangent(theta: float) -> FloatArray:
    """``M`` (6x3): ``planar_pose(v + dv) = planar_pose(v) Exp(M dv)`` to first order."""
    c, s = np.cos(theta), np.sin(theta)
    m = np.zeros((6, 3))
    m[2, 2] = 1.0
    m[3, 0], m[3, 1] = c, s
    m[4, 0], m[4, 1] = -s, c
    return m


def base_motion(T_i: gtsam.Pose3, T_j: gtsam.Pose3, T_base_cam: gtsam.Pose3) -> gtsam.Pose3:
    """``D = B_i^-1 B_j``: the base's motion implied by two camera poses (``B = T T_base_cam^-1``)."""
    return T_base_cam.compose(T_i.between(T_j)).compose(T_base_cam.inverse())


def wheel_odometry_error(T_i: gtsam.Pose3, T_j: gtsam.Pose3, T_base_cam: gtsam.Pose3, v: ArrayLike,
                         dv_dc: FloatArray | None = None) -> tuple[FloatArray, list[FloatArray] | None]:
    """``e = Log(planar_pose(v)^-1 D)`` (6); with ``dv_dc`` (3 x P) also ``[de/dxi_i, de/dxi_j, de/dc]``."""
    D = base_motion(T_i, T_j, T_base_cam)
    v = np.asarray(v, dtype=np.float64).reshape(3)
    Z = planar_pose(v)
    E = Z.between(D)
    e = np.asarray(gtsam.Pose3.Logmap(E), dtype=np.float64)
    if dv_dc is None:
        return e, None
    jr_inv = gtsam.Pose3.LogmapDerivative(E)
    ad_bc = T_base_cam.AdjointMap()
    h_j = jr_inv @ ad_bc
    h_i = -jr_inv @ D.inverse().AdjointMap() @ ad_bc
    h_c = -jr_inv @ E.inverse().AdjointMap() @ planar_tangent(v[2]) @ dv_dc
    return e, [h_i, h_j, h_c]


def wheel_step_sigmas(raw_motion: ArrayLike, translation_sigma: float, rotation_sigma: float,
                      per_metre: float, planar_rotation_sigma: float, planar_height_sigma: float) -> FloatArray:
    """The sigmas of one wheel factor's error (roll, pitch, yaw, x, y, z of the base):

    * yaw (rad) and x, y (m): the wheels' noise, ``rotation_sigma`` and ``translation_sigma`` per
      step plus ``per_metre`` times the distance driven (``|u_xy|``) in both (m/m and rad/m):
      a longer step (a blind stretch between keyframes) is less certain;
    * roll, pitch (rad): ``planar_rotation_sigma``; height change (m): ``planar_height_sigma``: how
      far from planar the base's motion between two keyframes may be (ramps, bumps).
    """
    u = np.asarray(raw_motion, dtype=np.float64).reshape(3)
    dist = float(np.hypot(u[0], u[1]))
    s = np.array([planar_rotation_sigma, planar_rotation_sigma, rotation_sigma + per_metre * dist,
                  translation_sigma + per_metre * dist, translation_sigma + per_metre * dist, planar_height_sigma],
                 dtype=np.float64)
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise InputError(f"wheel odometry sigmas must be positive, got {s.tolist()}")
    return s


class WheelOdometryFactor(PythonFactor):
    """The wheel-odometry factor on two camera poses and the calibration (module docstring).

    Args:
        key_i, key_j: Pose3 keys (``T_world_cam``) of the earlier and the later keyframe.
        key_calibration: the calibration vector's key (9 or 3 entries, per ``model``).
        raw_motion: the wheels' raw motion ``(dx, dy, dtheta)`` from ``t_i`` to ``t_j``.
        model: ``"linear"`` or ``"diff_drive"``.
        T_base_cam: the camera's pose in the base frame.
        sigmas: the error's 6 sigmas (:func:`wheel_step_sigmas`).
        nominal_baseline: the diff-drive model's nominal track width ``b0`` (m).
    """

    def __init__(self, key_i: int, key_j: int, key_calibration: int, raw_motion: ArrayLike, model: str,
                 T_base_cam: gtsam.Pose3, sigmas: Sequence[float], nominal_baseline: float = 1.0) -> None:
        nominal_calibration(model)  # checks the model's name
        self.model = model
        self.raw_motion = np.asarray(raw_motion, dtype=np.float64).reshape(3).copy()
        self.T_base_cam = T_base_cam
        self.nominal_baseline = float(nominal_baseline)
        self.sigmas = np.asarray(sigmas, dtype=np.float64).reshape(6).copy()
        self.keys3 = (key_i, key_j, key_calibration)
        super().__init__(gtsam.noiseModel.Diagonal.Sigmas(self.sigmas), [key_i, key_j, key_calibration])

    def error_and_jacobians(self, T_i: gtsam.Pose3, T_j: gtsam.Pose3, params: ArrayLike
                            ) -> tuple[FloatArray, list[FloatArray]]:
        """The (unwhitened) error and its Jacobians w.r.t. ``T_i``, ``T_j`` and the calibration."""
        v, dv = calibrated_motion(self.model, params, self.raw_motion, self.nominal_baseline)
        e, J = wheel_odometry_error(T_i, T_j, self.T_base_cam, v, dv)
        assert J is not None
        return e, J

    def whitened(self, T_i: gtsam.Pose3, T_j: gtsam.Pose3, params: ArrayLike) -> tuple[FloatArray, list[FloatArray]]:
        """``e / sigmas`` and its Jacobians (for solvers that assemble their own normal equations);
        the cost is ``|e / sigmas|^2 / 2``."""
        e, J = self.error_and_jacobians(T_i, T_j, params)
        return e / self.sigmas, [Ji / self.sigmas[:, None] for Ji in J]

    def _evaluate(self, this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        ki, kj, kc = self.keys3
        T_i, T_j, c = values.atPose3(ki), values.atPose3(kj), values.atVector(kc)
        if H is None:
            v, _ = calibrated_motion(self.model, c, self.raw_motion, self.nominal_baseline)
            return wheel_odometry_error(T_i, T_j, self.T_base_cam, v)[0]
        e, J = self.error_and_jacobians(T_i, T_j, c)
        H[0], H[1], H[2] = J
        return e
