"""The wheel-odometry factor (factors/wheel_odometry.py): its error and analytic Jacobians."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.wheel_odometry import (WheelOdometryFactor, base_motion, calibrated_motion, nominal_calibration,
                                    planar_pose, wheel_odometry_error, wheel_step_sigmas)
from gtvo.core.keys import calibration_key, pose_key
from gtvo.errors import InputError

#: a forward-looking camera 1.6 m above the base, 0.3 m ahead, slightly pitched down
R_BC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_BC = gtsam.Pose3(gtsam.Rot3(R_BC).compose(gtsam.Rot3.Rx(0.05)), gtsam.Point3(0.3, 0.02, 1.6))


def _random_pose(rng: np.random.Generator, scale: float = 1.0) -> gtsam.Pose3:
    return gtsam.Pose3.Expmap(np.concatenate([rng.normal(0, 0.3, 3), rng.normal(0, scale, 3)]))


def _numerical(fn, x0, retract, dim: int, h: float = 1e-6) -> np.ndarray:
    cols = []
    for k in range(dim):
        d = np.zeros(dim)
        d[k] = h
        cols.append((fn(retract(x0, d)) - fn(retract(x0, -d))) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("model,params", [
    ("linear", np.array([1.02, 0.01, -0.03, -0.02, 0.97, 0.05, 0.01, 0.02, 1.04])),
    ("diff_drive", np.array([0.98, 1.03, 1.05])),
])
def test_jacobians_match_numerical_derivatives(model: str, params: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        T_i = _random_pose(rng, 3.0)
        T_j = T_i.compose(_random_pose(rng, 1.0))
        u = np.array([rng.uniform(0.2, 2.0), rng.normal(0, 0.1), rng.normal(0, 0.4)])
        f = WheelOdometryFactor(pose_key(0), pose_key(1), calibration_key(), u, model, T_BC, np.ones(6), 0.55)
        e, J = f.error_and_jacobians(T_i, T_j, params)
        pose_retract = lambda T, d: T.retract(d)  # noqa: E731
        Ji = _numerical(lambda T: f.error_and_jacobians(T, T_j, params)[0], T_i, pose_retract, 6)
        Jj = _numerical(lambda T: f.error_and_jacobians(T_i, T, params)[0], T_j, pose_retract, 6)
        Jc = _numerical(lambda c: f.error_and_jacobians(T_i, T_j, c)[0], params, lambda c, d: c + d, params.size)
        np.testing.assert_allclose(J[0], Ji, atol=1e-6)
        np.testing.assert_allclose(J[1], Jj, atol=1e-6)
        np.testing.assert_allclose(J[2], Jc, atol=1e-6)


def test_gtsam_linearisation_is_the_analytic_one() -> None:
    """The CustomFactor hands GTSAM the whitened error and Jacobians of :meth:`whitened`."""
    rng = np.random.default_rng(5)
    T_i, T_j = _random_pose(rng), _random_pose(rng)
    params = np.array([0.99, 1.01, 1.02])
    f = WheelOdometryFactor(pose_key(0), pose_key(1), calibration_key(), [1.0, 0.05, 0.2], "diff_drive", T_BC,
                            np.array([0.01, 0.01, 0.02, 0.05, 0.05, 0.03]), 0.5)
    values = gtsam.Values()
    values.insert(pose_key(0), T_i)
    values.insert(pose_key(1), T_j)
    values.insert(calibration_key(), params)
    e, J = f.whitened(T_i, T_j, params)
    assert f.error(values) == pytest.approx(0.5 * e @ e)
    A, b = f.linearize(values).jacobian()
    np.testing.assert_allclose(A, np.hstack(J), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b, -e, rtol=1e-9, atol=1e-12)


def test_error_is_zero_for_a_consistent_planar_motion_and_sees_roll_pitch_height() -> None:
    """Camera poses of a base that moved by the calibrated wheel motion on its plane: e = 0; a tilt
    or a height change of the base shows in the planar terms (rows roll, pitch, z) alone."""
    params = np.array([1.1, 0.9, 1.2])
    u = np.array([0.8, 0.02, 0.3])
    v, _ = calibrated_motion("diff_drive", params, u, 0.5)
    B_i = gtsam.Pose3(gtsam.Rot3.Rz(0.7), gtsam.Point3(3.0, -1.0, 0.0))
    T_i = B_i.compose(T_BC)
    T_j = B_i.compose(planar_pose(v)).compose(T_BC)
    e, _ = wheel_odometry_error(T_i, T_j, T_BC, v)
    np.testing.assert_allclose(e, 0.0, atol=1e-12)
    bump = gtsam.Pose3(gtsam.Rot3.Rx(0.01), gtsam.Point3(0.0, 0.0, 0.02))
    T_j = B_i.compose(planar_pose(v)).compose(bump).compose(T_BC)
    e, _ = wheel_odometry_error(T_i, T_j, T_BC, v)
    assert abs(e[0]) == pytest.approx(0.01, rel=1e-6) and abs(e[5]) == pytest.approx(0.02, rel=1e-3)
    assert np.all(np.abs(e[[1, 2, 3, 4]]) < 1e-3)
    np.testing.assert_allclose(base_motion(T_i, T_i, T_BC).matrix(), np.eye(4), atol=1e-12)


def test_nominal_calibration_passes_the_raw_motion_through() -> None:
    """X = I, and k = 1 on an arc (the diff-drive model's raw motions are arcs of the nominal wheels)."""
    s, t = 0.9, 0.2
    u = np.array([s * np.sin(t) / t, s * (1 - np.cos(t)) / t, t])
    for model in ("linear", "diff_drive"):
        v, _ = calibrated_motion(model, nominal_calibration(model), u, 0.6)
        np.testing.assert_allclose(v, u, atol=1e-12)


def test_bad_model_and_sigmas_are_one_line_errors() -> None:
    with pytest.raises(InputError, match="unknown wheel model 'tracks'"):
        nominal_calibration("tracks")
    with pytest.raises(InputError, match="sigmas must be positive"):
        wheel_step_sigmas([1.0, 0.0, 0.0], 0.0, 0.01, 0.0, 0.01, 0.01)
    s = wheel_step_sigmas([3.0, 4.0, 0.0], 0.01, 0.002, 0.02, 0.005, 0.02)
    np.testing.assert_allclose(s, [0.005, 0.005, 0.102, 0.11, 0.11, 0.02])


@pytest.mark.parametrize("u", [[0.5, 0.0, 0.0], [0.5, 0.0, 3e-4], [0.0, 0.0, 0.0], [0.0, 0.0, 0.2]])
def test_jacobians_match_numerical_derivatives_driving_straight_standing_and_turning_on_the_spot(u) -> None:
    """The common motions of a ground robot: the diff-drive model's series branch (dtheta ~ 0) and no
    motion at all, with camera poses that do not fit them (a non-zero error)."""
    rng = np.random.default_rng(7)
    params = np.array([1.02, 0.97, 1.04])
    T_i = _random_pose(rng, 3.0)
    T_j = T_i.compose(_random_pose(rng, 0.5))
    f = WheelOdometryFactor(pose_key(0), pose_key(1), calibration_key(), u, "diff_drive", T_BC, np.ones(6), 0.5)
    e, J = f.error_and_jacobians(T_i, T_j, params)
    assert np.linalg.norm(e) > 0.1
    Jc = _numerical(lambda c: f.error_and_jacobians(T_i, T_j, c)[0], params, lambda c, d: c + d, 3)
    Jj = _numerical(lambda T: f.error_and_jacobians(T_i, T, params)[0], T_j, lambda T, d: T.retract(d), 6)
    np.testing.assert_allclose(J[2], Jc, atol=1e-6)
    np.testing.assert_allclose(J[1], Jj, atol=1e-6)
