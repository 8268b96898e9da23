"""The synthetic IMU (gtvo.datasets.synthetic_imu, gtvo synthetic --imu): integrating its noise-free
stream reproduces the exact trajectory; noise and bias walk at the given densities."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from gtvo.cli import main as cli_main
from gtvo.datasets import open_sequence
from gtvo.datasets.imu import ImuNoise
from gtvo.datasets.synthetic import make_synthetic_sequence, synthetic_poses_at
from gtvo.datasets.synthetic_imu import SYNTHETIC_GRAVITY, ImuSimulation, simulate_imu, true_imu_motion
from gtvo.errors import InputError


def _integrate(imu, t0, t1, poses_at, gyro_bias, accel_bias):
    """The IMU's pose at ``t1`` from its exact pose and velocity at ``t0``, by GTSAM's preintegration."""
    params = gtsam.PreintegrationCombinedParams(SYNTHETIC_GRAVITY)
    for set_cov in (params.setGyroscopeCovariance, params.setAccelerometerCovariance, params.setIntegrationCovariance):
        set_cov(np.eye(3) * 1e-8)
    bias = gtsam.imuBias.ConstantBias(np.asarray(accel_bias), np.asarray(gyro_bias))
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    for dt, w, a in zip(*imu.interval(t0, t1)):
        pim.integrateMeasurement(a, w, dt)
    h = 1e-4
    p = lambda t: (poses_at(np.array([t]))[0] @ imu.T_cam_imu)[:3, 3]  # noqa: E731
    start = gtsam.NavState(gtsam.Pose3(poses_at(np.array([t0]))[0] @ imu.T_cam_imu), (p(t0 + h) - p(t0 - h)) / (2 * h))
    return pim.predict(start, bias).pose()


@pytest.mark.parametrize("motion", ["swerve", "loop"])
def test_integrating_the_exact_stream_reproduces_the_trajectory(motion):
    poses_at = lambda t: synthetic_poses_at(t, 30, motion)  # noqa: E731
    true_end = poses_at(np.array([2.9]))[0]
    errors = []
    for rate in (500.0, 1000.0):
        sim = ImuSimulation(rate_hz=rate, noisy=False)
        imu = simulate_imu(0.0, 2.9, poses_at, sim)
        end = _integrate(imu, 0.0, 2.9, poses_at, sim.gyro_bias, sim.accel_bias)
        T_end = true_end @ imu.T_cam_imu
        errors.append((np.linalg.norm(end.translation() - T_end[:3, 3]),
                       np.linalg.norm(gtsam.Rot3.Logmap(end.rotation().between(gtsam.Rot3(T_end[:3, :3]))))))
    assert errors[1][0] < 5e-4 and errors[1][1] < 1e-5  # metres and radians after 2.9 s and several metres
    assert 1.6 < errors[0][0] / errors[1][0] < 2.4  # the discretisation's first order: the stream itself is exact


def test_at_rest_the_accelerometer_reads_gravity_up_and_the_gyro_nothing():
    still = lambda t: np.tile(np.eye(4), (len(t), 1, 1))  # noqa: E731
    omega, f = true_imu_motion(np.linspace(0, 1, 5), still, np.eye(4))
    np.testing.assert_allclose(omega, 0, atol=1e-12)
    np.testing.assert_allclose(f, np.tile([0, -9.80665, 0], (5, 1)), atol=1e-6)  # camera y is down


def test_noise_and_bias_walk_have_the_given_densities():
    still = lambda t: np.tile(np.eye(4), (len(t), 1, 1))  # noqa: E731
    noise = ImuNoise(1e-3, 1e-2, 1e-4, 1e-3)
    sim = ImuSimulation(rate_hz=400.0, noise=noise, gyro_bias=(0, 0, 0), accel_bias=(0, 0, 0), seed=3)
    imu = simulate_imu(0.0, 50.0, still, sim, T_cam_imu=np.eye(4))
    white = np.diff(imu.gyro, axis=0).std() / np.sqrt(2) * np.sqrt(imu.rate_hz ** -1)  # density = sigma * sqrt(dt)
    assert white == pytest.approx(1e-3, rel=0.05)
    drift = imu.gyro[-4000:].mean(axis=0) - imu.gyro[:4000].mean(axis=0)  # the walk over ~40 s
    assert np.all(np.abs(drift) < 5 * 1e-4 * np.sqrt(50.0))


def test_a_turning_motion_has_no_imu():
    with pytest.raises(InputError, match="not a smooth function of time"):
        make_synthetic_sequence(10, 64, 48, motion="turn", imu=ImuSimulation())


@pytest.mark.slow
def test_cli_writes_an_imu_that_run_picks_up(tmp_path, capsys):
    out = tmp_path / "log"
    assert cli_main(["synthetic", "--out", str(out), "--frames", "5", "--width", "64", "--height", "48",
                     "--motion", "swerve", "--imu", "--imu-rate", "250", "--imu-bias", "0.1,0,0,0,0,0.5",
                     "--imu-exact", "--no-progress"]) == 0
    assert "with an IMU (250 Hz)" in capsys.readouterr().out
    imu = open_sequence(out).imu
    assert imu.rate_hz == pytest.approx(250.0) and imu.times[-1] == pytest.approx(0.4)
    omega, f = true_imu_motion(imu.times, lambda t: synthetic_poses_at(t, 5, "swerve"), imu.T_cam_imu)
    np.testing.assert_allclose(imu.gyro - omega, np.tile([0.1, 0, 0], (len(imu), 1)), atol=1e-9)
    np.testing.assert_allclose(imu.accel - f, np.tile([0, 0, 0.5], (len(imu), 1)), atol=1e-9)
    assert cli_main(["synthetic", "--out", str(tmp_path / "x"), "--motion", "ground", "--imu"]) == 2
    assert "--imu needs a smooth --motion" in capsys.readouterr().err
