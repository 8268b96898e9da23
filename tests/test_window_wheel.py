"""Wheel odometry in the window (gtvo.window.wheel): the calibration variable in both solvers, carried
by the marginalisation prior, and what each motion observes."""

from __future__ import annotations

import copy
from types import SimpleNamespace

import gtsam
import numpy as np
import pytest

from factors.params import PhotometricConfig
from gtvo.core.keys import calibration_key, pose_key
from gtvo.config import WheelConfig
from gtvo.datasets.wheel import WheelOdometry, simulate_wheel_odometry
from gtvo.errors import InputError
from gtvo.window import (SlidingWindowOptimizer, WindowConfig, build_graph, solve_gtsam, solve_handrolled,
                         window_cost)
from gtvo.wheel_calibration.motions import integrate_motions
from gtvo.window.wheel import WheelCalibration, WheelSettings
from gtvo.datasets.synthetic import make_synthetic_sequence
from tests.test_window import _keyframes
from tests._window_problem import problem

T_BC = WheelConfig(base_to_camera=(0.2, 0.0, 1.0, -0.5, 0.5, -0.5, 0.5)).T_base_cam  # 1 m above the base
K_TRUE = np.array([1.03, 0.98, 1.05])
NO_HUBER = PhotometricConfig(huber_k=None)


@pytest.fixture(scope="module")
def seq():
    return make_synthetic_sequence(10, width=240, height=180, step_m=0.1)


def _wheel(seq, k_true=K_TRUE, **settings) -> WheelCalibration:
    log = simulate_wheel_odometry(seq.timestamps, np.asarray(seq.gt_poses), T_BC, "pose", k_true, nominal_baseline=0.5)
    return WheelCalibration(WheelSettings(gtsam.Pose3(T_BC), "diff_drive", 0.5, **settings), log)


def test_both_solvers_minimise_the_same_cost_with_wheels(seq):
    """The wheel factors and the calibration's prior are in the hand-rolled cost as GTSAM's graph
    has them, and both solvers reach the same poses and calibration."""
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4, 6, 8], perturb=(0.002, 0.006), points=150, timed=True)
    cfg = WindowConfig(max_iterations=30, relative_tolerance=1e-12)
    wheel = _wheel(seq)
    graph, values, _ = build_graph(problem(cam.left, cam.baseline, kfs, cfg, None, photometric=NO_HUBER, wheel=wheel))
    assert sum(1 for i in range(graph.size()) if calibration_key() in graph.at(i).keys()) == 5  # 4 factors, 1 prior
    without = window_cost(problem(cam.left, cam.baseline, kfs, cfg, photometric=NO_HUBER))
    with_wheels = window_cost(problem(cam.left, cam.baseline, kfs, cfg, photometric=NO_HUBER, wheel=wheel))
    assert graph.error(values) == pytest.approx(with_wheels, rel=1e-9)
    assert with_wheels - without > 1.0
    a, b = copy.deepcopy(kfs), copy.deepcopy(kfs)
    ra = solve_gtsam(problem(cam.left, cam.baseline, a, cfg, photometric=NO_HUBER, wheel=wheel))
    rb = solve_handrolled(problem(cam.left, cam.baseline, b, cfg, photometric=NO_HUBER, wheel=wheel))
    assert ra.cost == pytest.approx(rb.cost, rel=1e-4)
    assert max(np.abs(x.pose.localCoordinates(y.pose)).max() for x, y in zip(a, b)) < 3e-5
    np.testing.assert_allclose(ra.wheel_calibration, rb.wheel_calibration, atol=1e-4)
    assert np.abs(ra.wheel_calibration - 1.0).max() > 1e-3  # the wheels moved it
    np.testing.assert_array_equal(wheel.estimate, np.ones(3))  # the solvers do not change the owner


def test_the_marginal_prior_carries_the_calibration(seq):
    """Window of 3, 5 keyframes: the calibration stays in the marginal's keys, its prior is set once,
    the window updates the estimate, and its marginal sigma is below the prior's."""
    cam = seq.camera
    kfs = _keyframes(seq, [0, 2, 4, 6, 8], points=150, timed=True)
    wheel = _wheel(seq)
    w = SlidingWindowOptimizer(cam.left, cam.baseline, WindowConfig(size=3, max_iterations=6), wheel=wheel)
    for k in kfs:
        w.add_keyframe(k)
        w.optimize("gtsam")
    assert w.marginal is not None and calibration_key() in w.marginal.keys
    graph, _, _ = build_graph(problem(cam.left, cam.baseline, w.keyframes, w.config, w.marginal, wheel=wheel))
    priors = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.PriorFactorVector)
              and calibration_key() in graph.at(i).keys()]
    assert priors == []  # carried by the marginal prior, not set again
    assert not np.array_equal(wheel.estimate, np.ones(3))
    cov = w.wheel_covariance()
    assert cov is not None and cov.shape == (3, 3)
    assert np.sqrt(cov[0, 0]) < 0.5 * wheel.settings.prior_sigma
    report = wheel.report()
    assert report["model"] == "diff_drive" and report["sigmas"] is not None and report["observed"][0]
    assert report["source"] == wheel.log.source  # which log, and where the camera sat on the base
    b2c = np.array(report["base_to_camera"])
    np.testing.assert_allclose(b2c[:3], [0.2, 0.0, 1.0], atol=1e-12)
    assert abs(b2c[3:] @ [-0.5, 0.5, -0.5, 0.5]) == pytest.approx(1.0, abs=1e-12)


def _pose_graph_sigmas(motions: np.ndarray, model: str = "diff_drive") -> np.ndarray:
    """Marginal sigmas of the calibration from wheel factors between exactly known poses (tight
    priors on every pose): what the motions alone observe."""
    poses = integrate_motions(motions)
    times = np.arange(len(poses), dtype=float)
    log = WheelOdometry(times, "pose", poses, "test")
    wheel = WheelCalibration(WheelSettings(gtsam.Pose3(T_BC), model, 0.5), log)
    kfs = [SimpleNamespace(index=i, timestamp=t) for i, t in enumerate(times)]
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    T_bc = gtsam.Pose3(T_BC)
    for i, p in enumerate(poses):
        B = gtsam.Pose3(gtsam.Rot3.Rz(p[2]), gtsam.Point3(p[0], p[1], 0.0))
        values.insert(pose_key(i), B.compose(T_bc))
        graph.add(gtsam.PriorFactorPose3(pose_key(i), B.compose(T_bc), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for _, f in wheel.factors(kfs, lambda kf: pose_key(kf.index)):
        graph.add(f)
    graph.add(wheel.prior_factor())
    values.insert(calibration_key(), wheel.estimate)
    cov = gtsam.Marginals(graph, values).marginalCovariance(calibration_key())
    return np.sqrt(np.diag(cov))


def test_what_each_motion_observes():
    """Standing: nothing (every sigma the prior's); straight driving: the wheel scales but not the
    track width (its sigma the prior's); turning while driving: all three."""
    prior = WheelSettings.prior_sigma
    standing = _pose_graph_sigmas(np.zeros((20, 3)))
    np.testing.assert_allclose(standing, prior, rtol=1e-3)
    straight = _pose_graph_sigmas(np.tile([0.5, 0.0, 0.0], (20, 1)))
    assert straight[0] < 0.1 * prior and straight[1] < 0.1 * prior
    assert straight[2] == pytest.approx(prior, rel=1e-3)
    turning = _pose_graph_sigmas(np.array([[0.5, 0.02, 0.1 if i % 10 < 5 else -0.1] for i in range(20)]))
    assert np.all(turning < 0.2 * prior)  # measured 0.067, 0.067, 0.17 of it
    w = WheelCalibration(WheelSettings(gtsam.Pose3()), WheelOdometry(np.array([0.0, 1.0]), "pose", np.zeros((2, 3)), "test"))
    w.covariance = np.diag(np.full(3, prior ** 2))
    assert w.report()["observed"] == [False, False, False]


def test_wheel_settings_and_backend_checks(seq):
    with pytest.raises(InputError, match="diff_drive model has 3 finite parameters"):
        WheelSettings(gtsam.Pose3(), prior_mean=(1.0, 1.0)).mean()
    wheel = _wheel(seq)
    with pytest.raises(InputError, match="'lm' window backend only"):
        SlidingWindowOptimizer(seq.camera.left, seq.camera.baseline, WindowConfig(backend="fixed_lag"), wheel=wheel)
    far = WheelCalibration(WheelSettings(gtsam.Pose3()), wheel.log)
    far.estimate = np.array([1.2, 1.0, 1.0])
    far.covariance = np.diag([1e-4, 1e-4, 1e-2])
    assert "left_wheel_scale 1.2" in far.report()["warning"]
