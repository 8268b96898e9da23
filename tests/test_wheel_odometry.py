"""Wheel odometry readings (gtvo.datasets.wheel): motion between two times, coverage, simulation, checks."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.config import OdometryConfig, WheelConfig, config_from_dict
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.datasets.wheel import WheelOdometry, planar_base_poses, simulate_wheel_odometry
from gtvo.errors import InputError
from gtvo.wheel_calibration import apply_diff_drive, apply_linear, integrate_motions
from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs


def _planar_to_3d(poses: np.ndarray, height: float = 0.0) -> np.ndarray:
    """(N, 3) planar poses -> (N, 4, 4) base poses in a z-up world."""
    T = np.tile(np.eye(4), (len(poses), 1, 1))
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = poses[:, 0], poses[:, 1], height
    return T


def _arc_steps(n: int, seed: int = 0) -> np.ndarray:
    """Exact constant-curvature steps (a diff-drive robot between readings): turns both ways."""
    rng = np.random.default_rng(seed)
    s = rng.uniform(0.05, 0.2, n)
    t = rng.uniform(-0.15, 0.15, n)
    return diff_drive_motions_from_arcs(s - 0.25 * t, s + 0.25 * t, 0.5)


def test_between_is_the_integrated_motion_in_the_first_base_frame():
    steps = np.random.default_rng(3).normal(0, [0.2, 0.05, 0.3], (40, 3))  # not arcs: dy too
    poses = integrate_motions(steps, start=(1.0, -2.0, 0.7))
    odo = WheelOdometry(np.arange(41) * 0.1, "pose", poses, "test")
    for i, j in ((0, 1), (3, 17), (10, 40)):
        expected = integrate_motions(steps[i:j])[-1]  # composed from the base frame at i
        np.testing.assert_allclose(odo.between(i * 0.1, j * 0.1), expected, atol=1e-12)


def test_between_keeps_a_full_turn_unwrapped_and_interpolates():
    theta = np.linspace(0, 4 * np.pi, 9)  # logged wrapped, two turns on the spot
    poses = np.column_stack([np.zeros(9), np.zeros(9), np.angle(np.exp(1j * theta))])
    odo = WheelOdometry(np.arange(9.0), "pose", poses, "test")
    np.testing.assert_allclose(odo.between(0.0, 8.0), [0, 0, 4 * np.pi], atol=1e-12)
    np.testing.assert_allclose(odo.between(0.0, 0.5), [0, 0, np.pi / 4], atol=1e-12)


def test_arcs_and_poses_of_the_same_exact_arcs_agree():
    steps = _arc_steps(30)
    poses = integrate_motions(steps)
    s = 0.5 * steps[:, 2] * 0.5  # b0 t / 2
    arc = steps[:, 0] / np.where(np.abs(steps[:, 2]) > 0, np.sin(steps[:, 2]) / steps[:, 2], 1.0)
    arcs = np.concatenate([np.zeros((1, 2)), np.cumsum(np.column_stack([arc - s, arc + s]), axis=0)])
    t = np.arange(31) * 0.05
    by_pose = WheelOdometry(t, "pose", poses, "pose")
    by_arcs = WheelOdometry(t, "arcs", arcs, "arcs", nominal_baseline=0.5)
    for i, j in ((0, 1), (4, 5), (2, 30)):
        if j - i == 1:  # one exact arc: the same motion
            np.testing.assert_allclose(by_arcs.between(t[i], t[j]), by_pose.between(t[i], t[j]), atol=1e-12)
        else:  # several arcs are no arc: the heading and the path length still agree
            assert by_arcs.between(t[i], t[j])[2] == pytest.approx(by_pose.between(t[i], t[j])[2], abs=1e-12)


def test_simulated_without_error_or_noise_is_the_true_base_motion():
    base = integrate_motions(_arc_steps(60, seed=1), start=(2.0, 1.0, -0.3))
    T_base_cam = WheelConfig(base_to_camera=(0.3, -0.1, 1.2, -0.5, 0.5, -0.5, 0.5)).T_base_cam
    T_world_cam = _planar_to_3d(base, height=0.4) @ T_base_cam
    times = 10.0 + np.arange(61) * 0.1
    np.testing.assert_allclose(planar_base_poses(T_world_cam, T_base_cam)[-1],
                               integrate_motions(_arc_steps(60, seed=1))[-1], atol=1e-9)
    for kind, cal in (("pose", np.eye(3)), ("pose", (1.0, 1.0, 1.0)), ("arcs", (1.0, 1.0, 1.0))):
        odo = simulate_wheel_odometry(times, T_world_cam, T_base_cam, kind, cal, 0.0, 0, nominal_baseline=0.5)
        for i, j in ((0, 1), (5, 6), (0, 60)):
            expected = integrate_motions(_arc_steps(60, seed=1)[i:j])[-1]
            got = odo.between(times[i], times[j])
            if kind == "arcs" and j - i > 1:  # arcs compose to no arc: compare heading only
                assert got[2] == pytest.approx(expected[2], abs=1e-9)
            else:
                np.testing.assert_allclose(got, expected, atol=1e-9)


def test_the_true_calibration_maps_simulated_readings_to_the_true_motion():
    steps = _arc_steps(50, seed=2)
    T_world_cam = _planar_to_3d(integrate_motions(steps)) @ WheelConfig().T_base_cam
    times = np.arange(51) * 0.1
    X = np.array([[1.03, 0.0, 0.01], [0.0, 1.0, 0.02], [0.0, 0.0, 0.97]])
    p = np.array([1.02, 0.97, 1.06])
    lin = simulate_wheel_odometry(times, T_world_cam, WheelConfig().T_base_cam, "pose", X, 0.0, 0)
    dd = simulate_wheel_odometry(times, T_world_cam, WheelConfig().T_base_cam, "arcs", p, 0.0, 0,
                                 nominal_baseline=0.5)
    raw_lin = np.array([lin.between(times[k], times[k + 1]) for k in range(50)])
    raw_dd = np.array([dd.between(times[k], times[k + 1]) for k in range(50)])
    assert np.abs(raw_dd - steps).max() > 1e-3  # the error is there...
    np.testing.assert_allclose(apply_linear(X, raw_lin), steps, atol=1e-12)  # ...and the calibration undoes it
    np.testing.assert_allclose(apply_diff_drive(p, raw_dd, 0.5), steps, atol=1e-12)


def test_simulated_noise_is_seeded():
    steps = _arc_steps(20)
    T_world_cam = _planar_to_3d(integrate_motions(steps)) @ WheelConfig().T_base_cam
    args = (np.arange(21) * 0.1, T_world_cam, WheelConfig().T_base_cam, "arcs", (1, 1, 1), 0.01)
    a, b = (simulate_wheel_odometry(*args, seed=4, nominal_baseline=0.5) for _ in range(2))
    c = simulate_wheel_odometry(*args, seed=5, nominal_baseline=0.5)
    assert np.array_equal(a.values, b.values) and not np.array_equal(a.values, c.values)


def test_covers_only_the_logged_span():
    odo = WheelOdometry(np.array([1.0, 2.0, 3.0]), "pose", np.zeros((3, 3)), "test")
    assert odo.covers(1.0, 3.0) and odo.covers(1.5, 2.5)
    assert not odo.covers(0.9, 2.0) and not odo.covers(2.0, 3.1)  # started late, ended early
    with pytest.raises(InputError, match="does not cover"):
        odo.between(2.0, 3.5)


@pytest.mark.parametrize("times, values, match", [
    ([0.0, 0.1, 0.1, 0.3], np.zeros((4, 3)), "reading 2: time 0.1 s is not after"),
    ([0.0, 0.1, 0.2, 0.3], [[0, 0, 0], [0, 0, 0], [np.nan, 0, 0], [0, 0, 0]], "reading 2: not a finite"),
    ([0.0, 0.1], np.zeros((2, 2)), "needs 2 rows of 3 values"),
])
def test_bad_readings_name_the_reading(times, values, match):
    with pytest.raises(InputError, match=match):
        WheelOdometry(np.array(times), "pose", np.array(values, dtype=float), "f.csv")


def test_arcs_need_the_nominal_baseline():
    with pytest.raises(InputError, match="nominal baseline"):
        WheelOdometry(np.arange(3.0), "arcs", np.zeros((3, 2)), "f.csv")


def test_a_sequence_keeps_its_wheel_odometry_when_cut():
    seq = make_synthetic_sequence(n_frames=6, width=64, height=48)
    odo = WheelOdometry(seq.timestamps, "pose", np.zeros((6, 3)), "test")
    seq.wheel_odometry = odo
    assert seq.truncated(3).wheel_odometry is odo and seq.subsampled(2).wheel_odometry is odo
    assert make_synthetic_sequence(n_frames=2, width=64, height=48).wheel_odometry is None


def test_wheel_config_section():
    T = OdometryConfig().wheel.T_base_cam
    np.testing.assert_allclose(T[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # camera z = base x (forward)
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # camera x = base -y (right)
    cfg = config_from_dict({"wheel": {"model": "linear", "nominal_baseline": 0.6}})
    assert cfg.wheel.model == "linear" and cfg.wheel.nominal_baseline == 0.6
    with pytest.raises(InputError, match="wheel.base_to_camera.*unit quaternion"):
        config_from_dict({"wheel": {"base_to_camera": [0, 0, 0, 0, 0, 0, 2]}})
    with pytest.raises(InputError, match="wheel.model"):
        config_from_dict({"wheel": {"model": "tank"}})
    with pytest.raises(InputError, match="wheel.calibration_prior.*scales must be positive"):
        config_from_dict({"wheel": {"calibration_prior": [1.0, 1.0, 0.0]}})
    with pytest.raises(InputError, match="wheel.calibration_prior.*X must be invertible"):
        config_from_dict({"wheel": {"model": "linear", "calibration_prior": [1, 0, 0, 1, 0, 0, 0, 0, 1]}})
