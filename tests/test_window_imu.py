"""The IMU in the window (gtvo.window.imu): the initialisation, both solvers on the IMU factors
(the hand-rolled one through the factors' own linearisation), and the marginalisation of the
keyframes' velocities and biases."""

from __future__ import annotations

import copy
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

from factors.params import PhotometricConfig
from gtvo.core.keys import gravity_tilt_key, imu_bias_key, velocity_key
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.datasets.synthetic_imu import SYNTHETIC_GRAVITY, ImuSimulation, simulate_imu
from gtvo.errors import InputError
from gtvo.window import SlidingWindowOptimizer, WindowConfig, build_graph, solve_gtsam, solve_handrolled
from gtvo.window.imu import ImuWindow, ImuWindowSettings
from tests._window_problem import problem
from tests.test_window import _keyframes

NO_HUBER = PhotometricConfig(huber_k=None)
TRUE_BIAS = (0.01, -0.02, 0.015, 0.05, -0.03, 0.08)  # gyro, accel


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(24, width=240, height=180, motion="swerve",
                                   imu=ImuSimulation(gyro_bias=TRUE_BIAS[:3], accel_bias=TRUE_BIAS[3:]))


def _initialised(seq, frames, **settings) -> tuple[ImuWindow, list]:
    kfs = _keyframes(seq, frames, points=150, timed=True)
    imu = ImuWindow(seq.imu, ImuWindowSettings(**settings))
    for k in range(len(kfs)):
        imu.keyframe_added(kfs[:k + 1])
    return imu, kfs


def test_moving_initialisation_finds_gravity_gyro_bias_and_velocities(seq):
    imu, kfs = _initialised(seq, range(0, 24, 2))
    assert imu.init_kind == "moving"
    angle = np.degrees(np.arccos(imu.gravity @ SYNTHETIC_GRAVITY / np.linalg.norm(imu.gravity) / 9.80665))
    # the accelerometer bias (|b_a| = 0.1 m/s^2, not estimated at the start) may tilt it by up to 0.58 deg
    assert angle < 0.5 and np.linalg.norm(imu.gravity) == pytest.approx(9.80665)
    assert 0 < imu.gravity_sigma_deg < 1.0
    np.testing.assert_allclose(imu.init_bias[3:], TRUE_BIAS[:3], atol=0.2 * 0.02)  # gyro within 20 % of the largest
    assert set(imu.velocities) == {kf.index for kf in kfs}
    assert abs(np.linalg.norm(imu.velocities[kfs[3].index]) - 1.5) < 0.15  # 0.15 m per frame at 10 Hz


def test_a_static_start_takes_gravity_from_the_accelerometer():
    T = np.eye(4)
    T[:3, :3] = gtsam.Rot3.Ypr(0.4, 0.2, -0.1).matrix()  # a tilted camera that does not move
    still = lambda t: np.tile(T, (len(t), 1, 1))  # noqa: E731
    readings = simulate_imu(0.0, 3.0, still, ImuSimulation(gyro_bias=(0.002, 0.0, -0.001), accel_bias=(0, 0, 0)))
    imu = ImuWindow(readings)
    kfs = [SimpleNamespace(index=k, timestamp=0.5 * k, pose=gtsam.Pose3(T)) for k in range(4)]
    for k in range(len(kfs)):
        imu.keyframe_added(kfs[:k + 1])
    assert imu.init_kind == "static"
    angle = np.degrees(np.arccos(imu.gravity @ SYNTHETIC_GRAVITY / np.linalg.norm(imu.gravity) / 9.80665))
    assert angle < 0.05 and imu.gravity_sigma_deg < 0.05
    np.testing.assert_allclose(imu.init_bias[3:], [0.002, 0.0, -0.001], atol=6e-4)  # 1 s of white noise
    assert all(np.array_equal(imu.velocities[k], np.zeros(3)) for k in range(3))  # initialised at 1 s
    assert np.linalg.norm(imu.velocities[3]) < 0.05  # predicted by the readings
    single = ImuWindow(readings)  # a static log makes one keyframe: initialised when the run finishes
    single.keyframe_added(kfs[:1])
    assert not single.initialised and single.try_initialise(kfs[:1], finishing=True)


def test_both_solvers_minimise_the_same_cost_with_the_imu(seq):
    imu, kfs = _initialised(seq, range(0, 24, 2))
    window = copy.deepcopy(kfs[-5:])
    for k in window[1:]:
        k.pose = k.pose.retract(np.r_[0.003, -0.002, 0.001, 0.01, -0.01, 0.005])
    cam = seq.camera
    cfg = WindowConfig(max_iterations=30, relative_tolerance=1e-12)

    def with_imu(kfs):
        p = problem(cam.left, cam.baseline, kfs, cfg, photometric=NO_HUBER)
        imu.add_to(p)
        return p

    graph, values, _ = build_graph(with_imu(window))
    assert imu.factors_added == 4 and values.exists(velocity_key(window[0].index))
    a, b = copy.deepcopy(window), copy.deepcopy(window)
    ra = solve_gtsam(with_imu(a))
    rb = solve_handrolled(with_imu(b))
    assert ra.cost == pytest.approx(rb.cost, rel=1e-4)
    # a turn of the whole window against gravity's tilt is held by the gauge and tilt priors alone:
    # flat, so the two solvers stop a little apart along it
    assert max(np.abs(x.pose.localCoordinates(y.pose)).max() for x, y in zip(a, b)) < 3e-4
    np.testing.assert_allclose(ra.variables.atVector(gravity_tilt_key()), rb.variables.atVector(gravity_tilt_key()),
                               atol=3e-4)
    for k in window:
        bias_a, bias_b = ra.variables.atVector(imu_bias_key(k.index)), rb.variables.atVector(imu_bias_key(k.index))
        np.testing.assert_allclose(bias_a[3:], bias_b[3:], atol=2e-5)  # gyro
        np.testing.assert_allclose(bias_a[:3], bias_b[:3], atol=2e-3)  # accelerometer: along the flat tilt
        np.testing.assert_allclose(ra.variables.atVector(velocity_key(k.index)),
                                   rb.variables.atVector(velocity_key(k.index)), atol=5e-4)
    assert ra.cost < 0.5 * ra.initial_cost


def test_the_marginal_prior_carries_velocities_and_biases(seq):
    cam = seq.camera
    kfs = _keyframes(seq, range(0, 24, 2), points=120, timed=True)
    imu = ImuWindow(seq.imu)
    w = SlidingWindowOptimizer(cam.left, cam.baseline, WindowConfig(size=4, max_iterations=6))
    w.use_imu(imu)
    for k in kfs:
        w.add_keyframe(k)
        w.optimize("gtsam")
    assert imu.initialised and w.marginal is not None
    oldest = w.keyframes[0].index
    assert imu_bias_key(oldest) in w.marginal.keys and velocity_key(oldest) in w.marginal.keys
    graph, _, _ = build_graph(w.problem())
    priors = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.PriorFactorVector)
              and imu_bias_key(oldest) in graph.at(i).keys()]
    assert priors == []  # carried by the marginal prior, not set again
    gyro = imu.biases[w.keyframes[-1].index][3:]
    np.testing.assert_allclose(gyro, TRUE_BIAS[:3], atol=0.2 * 0.02)
    with pytest.raises(InputError, match="'lm' window backend only"):
        SlidingWindowOptimizer(cam.left, cam.baseline, WindowConfig(backend="fixed_lag")).use_imu(imu)


def test_the_gyro_turns_the_camera_before_the_initialisation():
    """Before gravity and the velocities are known the gyro alone measures the camera's turn
    (:meth:`ImuWindow.camera_rotation`, the tracker's first guess then): on the exact stream of the
    fast-turning motion, 0.3 s turning 14 deg, within 0.01 deg of the truth; with the gyro bias of
    the default simulation not yet estimated, within its 0.3 s x 0.027 rad/s; None off the readings."""
    from gtvo.datasets.synthetic import synthetic_poses_at  # noqa: PLC0415

    poses = lambda t: synthetic_poses_at(t, 30, "swerve")  # noqa: E731
    for simulation, tol_deg in ((ImuSimulation(noisy=False, gyro_bias=(0, 0, 0)), 0.01),
                                (ImuSimulation(noisy=False), 0.3 * 0.027 * 180 / np.pi)):
        imu = ImuWindow(simulate_imu(0.0, 2.0, poses, simulation))
        assert not imu.initialised
        T0, T1 = poses(np.array([0.1, 0.4]))
        truth = gtsam.Rot3(T0[:3, :3].T @ T1[:3, :3])
        R = imu.camera_rotation(0.1, 0.4)
        assert np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(truth))) > 10
        assert np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(truth.between(R)))) < tol_deg
    assert imu.camera_rotation(1.9, 2.5) is None and imu.camera_rotation(0.4, 0.1) is None


def test_the_moving_initialisation_waits_for_three_keyframe_pairs(seq):
    """Two pairs of keyframes fit any poses exactly (12 equations for 3 velocities and gravity): no
    residual, a zero sigma, no check can refuse; the initialisation waits for a third pair."""
    imu, kfs = _initialised(seq, [0, 5, 10])
    assert kfs[-1].timestamp - kfs[0].timestamp >= imu.settings.init_seconds and not imu.initialised
    imu.keyframe_added(kfs + _keyframes(seq, [14], points=150, timed=True))
    assert imu.init_kind == "moving" and imu.gravity_sigma_deg > 0
