"""The IMU factor (factors.imu): zero at the exact motion, its Jacobians against numerical ones
(the camera-to-IMU chain is gtvo's), and the bias's and velocity's priors."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.imu import imu_factor, imu_params, preintegrate
from gtvo.core.keys import gravity_tilt_key, imu_bias_key, pose_key, velocity_key
from gtvo.datasets.synthetic import synthetic_poses_at
from gtvo.datasets.synthetic_imu import SYNTHETIC_GRAVITY, SYNTHETIC_T_CAM_IMU, ImuSimulation, simulate_imu

KEYS = [pose_key(0), velocity_key(0), pose_key(1), velocity_key(1), imu_bias_key(0), imu_bias_key(1)]


def _poses(t):
    return synthetic_poses_at(t, 40, "swerve")


def _imu_velocity(t, h=1e-5):
    p = lambda s: (_poses(np.array([s]))[0] @ SYNTHETIC_T_CAM_IMU)[:3, 3]  # noqa: E731
    return (p(t + h) - p(t - h)) / (2 * h)


def _factor_and_values(rate=1000.0, t0=0.5, t1=0.9, bias=(0.01, -0.02, 0.015, 0.05, -0.03, 0.08), tilt=None):
    sim = ImuSimulation(rate_hz=rate, noisy=False, gyro_bias=bias[:3], accel_bias=bias[3:])
    imu = simulate_imu(0.0, 2.0, _poses, sim)
    b = np.r_[bias[3:], bias[:3]]  # (b_accel, b_gyro)
    pim = preintegrate(imu_params(1.7e-4, 2e-3, 2e-5, 3e-3, SYNTHETIC_GRAVITY), b, *imu.interval(t0, t1))
    values = gtsam.Values()
    T = _poses(np.array([t0, t1]))
    values.insert(KEYS[0], gtsam.Pose3(T[0]))
    values.insert(KEYS[2], gtsam.Pose3(T[1]))
    values.insert(KEYS[1], _imu_velocity(t0))
    values.insert(KEYS[3], _imu_velocity(t1))
    values.insert(KEYS[4], b.copy())
    values.insert(KEYS[5], b.copy())
    if tilt is None:
        return imu_factor(*KEYS, pim, SYNTHETIC_T_CAM_IMU), values
    values.insert(gravity_tilt_key(), np.asarray(tilt, dtype=float))
    return imu_factor(*KEYS, pim, SYNTHETIC_T_CAM_IMU, gravity_tilt_key()), values


def test_the_exact_motion_costs_almost_nothing_and_a_wrong_one_much():
    factor, values = _factor_and_values()
    residual = factor.whitenedError(values)
    assert residual.shape == (15,)
    assert factor.error(values) < 0.5  # discretisation only: whitened residuals below 1
    moved = gtsam.Values(values)
    moved.update(KEYS[2], values.atPose3(KEYS[2]).retract(np.r_[0, 0, 0, 0.01, 0, 0]))  # 1 cm
    assert factor.error(moved) > 100 * max(factor.error(values), 1e-3)


def test_a_tilted_gravity_is_a_tilted_world():
    """The factor with gravity tilted by ``theta`` at poses and velocities turned by ``Exp(theta)``
    costs what the untilted factor costs at the originals."""
    factor, values = _factor_and_values()
    theta = np.array([0.02, -0.01, 0.03])
    tilted, moved = _factor_and_values(tilt=theta)
    R = gtsam.Pose3(gtsam.Rot3.Expmap(theta), np.zeros(3))
    for k in (KEYS[0], KEYS[2]):
        moved.update(k, R.compose(values.atPose3(k)))
    for k in (KEYS[1], KEYS[3]):
        moved.update(k, R.rotation().rotate(values.atVector(k)))
    np.testing.assert_allclose(tilted.whitenedError(moved), factor.whitenedError(values), atol=1e-6)


@pytest.mark.parametrize("seed, tilt", [(0, None), (1, None), (2, (0.02, -0.01, 0.03))])
def test_jacobians_match_numerical_derivatives(seed, tilt):
    factor, values = _factor_and_values(tilt=tilt)
    rng = np.random.default_rng(seed)
    start = gtsam.Values(values)  # away from the optimum, so every Jacobian block matters
    start.update(KEYS[0], values.atPose3(KEYS[0]).retract(rng.normal(size=6) * 0.01))
    start.update(KEYS[3], values.atVector(KEYS[3]) + rng.normal(size=3) * 0.1)
    start.update(KEYS[5], values.atVector(KEYS[5]) + rng.normal(size=6) * 0.01)
    lin = factor.linearize(start)
    A, b = lin.getA(), lin.getb()
    np.testing.assert_allclose(-b, factor.whitenedError(start), rtol=1e-12, atol=1e-12)
    numeric, h = [], 1e-6
    for key in lin.keys():
        dim = 6 if key in (KEYS[0], KEYS[2], KEYS[4], KEYS[5]) else 3  # velocities, the tilt: 3
        for axis in range(dim):
            sides = []
            for sign in (1.0, -1.0):
                step = np.zeros(dim)
                step[axis] = sign * h
                moved = gtsam.Values(start)
                if key in (KEYS[0], KEYS[2]):
                    moved.update(key, start.atPose3(key).retract(step))
                else:
                    moved.update(key, start.atVector(key) + step)
                sides.append(factor.whitenedError(moved))
            numeric.append((sides[0] - sides[1]) / (2 * h))
    numeric = np.array(numeric).T
    assert np.abs(numeric - A).max() < 1e-6 * max(np.abs(A).max(), 1.0)
