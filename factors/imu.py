"""The IMU between two keyframes: GTSAM's preintegrated measurements and ``CombinedImuFactor`` on the
window's variables (docs/imu.md, "The IMU factor").

Between keyframes ``i`` and ``j`` the readings are preintegrated once
(``gtsam.PreintegratedCombinedMeasurements``, at the bias estimate of ``i``; a later bias is
corrected to first order by the factor itself, Forster et al.'s on-manifold preintegration). The
factor ties the camera poses ``T_world_cam`` (the IMU's pose is ``T_world_imu = T_world_cam T_cam_imu``,
composed here with its Jacobian ``Ad(T_cam_imu^-1)``: exact for any lever arm, where GTSAM's
``body_P_sensor`` leaves out the angular acceleration's term), the velocities ``v`` of the IMU in the
world (m/s) and the biases ``b = (b_accel, b_gyro)`` (GTSAM's ``imuBias.ConstantBias`` order) of both
keyframes: 9 residuals of the preintegrated rotation, velocity and position and 6 of the bias
random walk.

The window keeps velocities and biases as plain vectors (3 and 6), so both solvers treat them as
any vector variable; :func:`imu_factor` wraps the ``CombinedImuFactor`` in a ``gtsam.CustomFactor``
whose error and Jacobians are the GTSAM factor's own linearisation (whitened: the custom factor's
noise model is the unit one). A bias vector's tangent is the bias's own (``ConstantBias`` retracts
by addition), so the Jacobians carry over unchanged.
"""

from __future__ import annotations

from typing import Sequence

import gtsam
import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: The variance of the integration's own error (m^2/s^4/Hz... GTSAM's ``integrationCovariance``).
INTEGRATION_VARIANCE = 1e-8
#: Residuals of a combined IMU factor: rotation, velocity, position, bias walk.
IMU_RESIDUALS = 15


def imu_params(gyro_noise_density: float, accel_noise_density: float, gyro_random_walk: float,
               accel_random_walk: float, gravity_world: ArrayLike) -> gtsam.PreintegrationCombinedParams:
    """GTSAM's preintegration parameters: continuous-time noise densities squared as covariances and
    gravity ``gravity_world`` (m/s^2, in the window's world frame); the preintegration is in the
    IMU's frame."""
    params = gtsam.PreintegrationCombinedParams(np.asarray(gravity_world, dtype=np.float64).reshape(3))
    params.setGyroscopeCovariance(np.eye(3) * float(gyro_noise_density) ** 2)
    params.setAccelerometerCovariance(np.eye(3) * float(accel_noise_density) ** 2)
    params.setBiasOmegaCovariance(np.eye(3) * float(gyro_random_walk) ** 2)
    params.setBiasAccCovariance(np.eye(3) * float(accel_random_walk) ** 2)
    params.setIntegrationCovariance(np.eye(3) * INTEGRATION_VARIANCE)
    return params


def constant_bias(bias: ArrayLike) -> gtsam.imuBias.ConstantBias:
    """``(b_accel, b_gyro)`` (6,) as GTSAM's bias."""
    b = np.asarray(bias, dtype=np.float64).reshape(6)
    return gtsam.imuBias.ConstantBias(b[:3].copy(), b[3:].copy())


def preintegrate(params: gtsam.PreintegrationCombinedParams, bias: ArrayLike, dt: ArrayLike, gyro: ArrayLike,
                 accel: ArrayLike) -> gtsam.PreintegratedCombinedMeasurements:
    """The readings ``(dt (M,), gyro (M, 3), accel (M, 3))`` preintegrated at ``bias`` (6,)."""
    pim = gtsam.PreintegratedCombinedMeasurements(params, constant_bias(bias))
    for d, w, a in zip(np.asarray(dt, dtype=np.float64), np.asarray(gyro, dtype=np.float64),
                       np.asarray(accel, dtype=np.float64)):
        pim.integrateMeasurement(a, w, float(d))
    return pim


def _combined(keys: Sequence[int], pim: gtsam.PreintegratedCombinedMeasurements) -> gtsam.CombinedImuFactor:
    return gtsam.CombinedImuFactor(*keys, pim)


def _inner_values(keys: Sequence[int], values: gtsam.Values, T_cam_imu: gtsam.Pose3, R_tilt: gtsam.Rot3
                  ) -> gtsam.Values:
    """The custom factor's variables as the GTSAM factor wants them: the IMU's poses and velocities in
    the tilted world (``R_tilt^T`` applied: gravity is the parameters' there), velocities as Vector3,
    biases as ConstantBias."""
    pose_i, vel_i, pose_j, vel_j, bias_i, bias_j = keys[:6]
    untilt = gtsam.Pose3(R_tilt.inverse(), np.zeros(3))
    out = gtsam.Values()
    out.insert(pose_i, untilt.compose(values.atPose3(pose_i).compose(T_cam_imu)))
    out.insert(pose_j, untilt.compose(values.atPose3(pose_j).compose(T_cam_imu)))
    out.insertPoint3(vel_i, R_tilt.unrotate(np.asarray(values.atVector(vel_i), dtype=np.float64)))
    out.insertPoint3(vel_j, R_tilt.unrotate(np.asarray(values.atVector(vel_j), dtype=np.float64)))
    out.insert(bias_i, constant_bias(values.atVector(bias_i)))
    out.insert(bias_j, constant_bias(values.atVector(bias_j)))
    return out


def so3_right_jacobian(w: ArrayLike) -> FloatArray:
    """``J_r(w)``: ``Exp(w + e) = Exp(w) Exp(J_r(w) e)`` to first order."""
    w = np.asarray(w, dtype=np.float64).reshape(3)
    th = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-8:
        return np.eye(3) - 0.5 * W
    return (np.eye(3) - (1.0 - np.cos(th)) / th ** 2 * W + (th - np.sin(th)) / th ** 3 * (W @ W))


def imu_factor(pose_i: int, velocity_i: int, pose_j: int, velocity_j: int, bias_i: int, bias_j: int,
               pim: gtsam.PreintegratedCombinedMeasurements, T_cam_imu: ArrayLike,
               gravity_tilt: int | None = None) -> gtsam.CustomFactor:
    """The combined IMU factor between two keyframes' camera poses, IMU velocities (3) and biases (6)
    (module doc): its error is the ``CombinedImuFactor``'s whitened error at the IMU's poses, its
    Jacobians that factor's whitened ones (``factor.linearize(values)``), the poses' carried to the
    camera's by ``Ad(T_cam_imu^-1)`` (right perturbations: ``T_wc Exp(xi) T_ci = T_wc T_ci Exp(Ad xi)``).

    ``gravity_tilt``: the key of a rotation vector ``theta`` (3) that tilts the parameters' gravity
    ``g0`` to ``g = Exp(theta) g0`` (the window refines gravity's direction with it); the GTSAM factor
    is evaluated in the frame where gravity is ``g0``: poses ``R^T T``, velocities ``R^T v`` with
    ``R = Exp(theta)``. A tilt ``e`` of ``theta`` turns that frame by ``phi = -J_r(theta) e`` on the
    left: a pose ``T'`` moves by ``Ad(T'^-1) [phi; 0]`` on the right, a velocity by ``phi x v'``."""
    keys = [pose_i, velocity_i, pose_j, velocity_j, bias_i, bias_j]
    inner = _combined(keys, pim)
    if gravity_tilt is not None:
        keys = keys + [gravity_tilt]
    T_ci = gtsam.Pose3(np.asarray(T_cam_imu, dtype=np.float64))
    to_camera = T_ci.inverse().AdjointMap()

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list | None) -> FloatArray:
        theta = np.zeros(3) if gravity_tilt is None else np.asarray(values.atVector(gravity_tilt), dtype=np.float64)
        R_tilt = gtsam.Rot3.Expmap(theta)
        v = _inner_values(keys, values, T_ci, R_tilt)
        if jacobians is None:
            return np.asarray(inner.whitenedError(v), dtype=np.float64)
        lin = inner.linearize(v)
        A = lin.getA()
        at = 0
        blocks = {}
        for key in lin.keys():
            n = 6 if key in (pose_i, pose_j, bias_i, bias_j) else 3
            blocks[key] = np.asarray(A[:, at:at + n], dtype=np.float64)
            at += n
        R_t = R_tilt.matrix().T
        for k, key in enumerate(keys[:6]):
            J = blocks[key]
            jacobians[k] = J @ to_camera if key in (pose_i, pose_j) else J @ R_t if key in (velocity_i, velocity_j) else J
        if gravity_tilt is not None:
            J_phi = np.zeros((IMU_RESIDUALS, 3))  # d residual / d phi (the frame's left turn)
            for pose_key, vel_key in ((pose_i, velocity_i), (pose_j, velocity_j)):
                T_prime = v.atPose3(pose_key)
                J_phi += blocks[pose_key] @ T_prime.inverse().AdjointMap()[:, :3]
                vp = np.asarray(v.atPoint3(vel_key), dtype=np.float64)
                J_phi += blocks[vel_key] @ -np.array([[0.0, -vp[2], vp[1]], [vp[2], 0.0, -vp[0]], [-vp[1], vp[0], 0.0]])
            jacobians[6] = J_phi @ -so3_right_jacobian(theta)
        return -np.asarray(lin.getb(), dtype=np.float64)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(IMU_RESIDUALS), keys, error)


def bias_prior(key: int, mean: ArrayLike, accel_sigma: float, gyro_sigma: float) -> gtsam.PriorFactorVector:
    """A prior on a bias vector ``(b_accel, b_gyro)``."""
    sigmas = np.r_[np.full(3, float(accel_sigma)), np.full(3, float(gyro_sigma))]
    return gtsam.PriorFactorVector(key, np.asarray(mean, dtype=np.float64).reshape(6),
                                   gtsam.noiseModel.Diagonal.Sigmas(sigmas))


def velocity_prior(key: int, mean: ArrayLike, sigma: float) -> gtsam.PriorFactorVector:
    """A prior on a velocity vector (m/s)."""
    return gtsam.PriorFactorVector(key, np.asarray(mean, dtype=np.float64).reshape(3),
                                   gtsam.noiseModel.Isotropic.Sigma(3, float(sigma)))
