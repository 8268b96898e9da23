"""Odometry calibration with GTSAM: factors (numeric Jacobians), LM == hand-rolled, joint calibration, CLI."""

from __future__ import annotations

import json

import gtsam
import numpy as np
import pytest

import gtvo.cli
from gtvo.core.keys import calibration_key, pose_key
from factors.odometry_calibration import (calibrated_odometry_error, calibrated_odometry_factor,
                                          diff_drive_calibration_factor, linear_calibration_factor)
from gtvo.wheel_calibration import (LoopClosure, PosePrior, apply_linear, fit_diff_drive, fit_diff_drive_gtsam, fit_linear,
                              fit_linear_gtsam, integrate_motions, joint_calibration, position_rmse)
from gtvo.wheel_calibration.diff_drive import apply_diff_drive
from gtvo.errors import InputError

X_TRUE = np.array([[1.05, 0.10, 0.02], [0.01, 0.95, 0.03], [0.005, -0.05, 0.90]])
JAC_ATOL = 1e-8  # central differences with eps = 1e-6 on quantities of order 1


def random_motions(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(0.3, 0.7, n), rng.normal(0, 0.1, n), rng.normal(0, 0.15, n)])


def linearized(factor: gtsam.CustomFactor, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) of the factor's linearisation (unit noise: A = de/dvars, b = -e)."""
    return factor.linearize(values).jacobian()


def test_linear_factor_jacobian_and_error():
    key = calibration_key()
    u, ref = np.array([0.4, -0.05, 0.1]), np.array([0.42, 0.0, 0.09])
    f = linear_calibration_factor(key, u, ref, gtsam.noiseModel.Unit.Create(3))
    x = X_TRUE.ravel()
    v = gtsam.Values()
    v.insert(key, x)
    a, b = linearized(f, v)
    np.testing.assert_allclose(-b, ref - X_TRUE @ u, atol=1e-15)
    eps = 1e-6

    def err(xx):
        vv = gtsam.Values()
        vv.insert(key, xx)
        return f.unwhitenedError(vv)
    num = np.column_stack([(err(x + eps * d) - err(x - eps * d)) / (2 * eps) for d in np.eye(9)])
    np.testing.assert_allclose(a, num, atol=JAC_ATOL)


def test_diff_drive_factor_jacobian():
    key = calibration_key()
    u, ref, p = np.array([0.3, 0.01, 0.2]), np.array([0.31, 0.02, 0.21]), np.array([1.02, 0.97, 1.1])
    f = diff_drive_calibration_factor(key, u, ref, 0.5, gtsam.noiseModel.Unit.Create(3))

    def err(pp):
        vv = gtsam.Values()
        vv.insert(key, pp)
        return f.unwhitenedError(vv)
    v = gtsam.Values()
    v.insert(key, p)
    a, b = linearized(f, v)
    np.testing.assert_allclose(-b, ref - apply_diff_drive(p, u[None], 0.5)[0], atol=1e-15)
    eps = 1e-6
    num = np.column_stack([(err(p + eps * d) - err(p - eps * d)) / (2 * eps) for d in np.eye(3)])
    np.testing.assert_allclose(a, num, atol=JAC_ATOL)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibrated_odometry_factor_jacobians(seed):
    rng = np.random.default_rng(seed)
    pi = gtsam.Pose2(*rng.normal(0, 2, 3))
    pj = pi.compose(gtsam.Pose2(*(rng.normal(0, 0.5, 3) + [0.5, 0, 0])))
    x = (X_TRUE + 0.05 * rng.normal(size=(3, 3))).ravel()
    u = rng.normal(0, 0.5, 3)
    ki, kj, kc = pose_key(0), pose_key(1), calibration_key()
    f = calibrated_odometry_factor(ki, kj, kc, u, gtsam.noiseModel.Unit.Create(3))
    v = gtsam.Values()
    v.insert(ki, pi)
    v.insert(kj, pj)
    v.insert(kc, x)
    e, jac = calibrated_odometry_error(pi, pj, x, u, with_jacobians=True)
    a, b = linearized(f, v)
    np.testing.assert_allclose(-b, e, atol=1e-14)
    np.testing.assert_allclose(a, np.hstack(jac), atol=1e-14)  # the factor hands GTSAM these Jacobians
    # the residual is BetweenFactorPose2's, with the measurement Pose2(X u)
    native = gtsam.BetweenFactorPose2(ki, kj, gtsam.Pose2(*(x.reshape(3, 3) @ u)), gtsam.noiseModel.Unit.Create(3))
    np.testing.assert_allclose(e, native.unwhitenedError(v), atol=1e-12)
    eps = 1e-6
    num_i = np.column_stack([(calibrated_odometry_error(pi.retract(eps * d), pj, x, u)
                              - calibrated_odometry_error(pi.retract(-eps * d), pj, x, u)) / (2 * eps) for d in np.eye(3)])
    num_j = np.column_stack([(calibrated_odometry_error(pi, pj.retract(eps * d), x, u)
                              - calibrated_odometry_error(pi, pj.retract(-eps * d), x, u)) / (2 * eps) for d in np.eye(3)])
    num_c = np.column_stack([(calibrated_odometry_error(pi, pj, x + eps * d, u)
                              - calibrated_odometry_error(pi, pj, x - eps * d, u)) / (2 * eps) for d in np.eye(9)])
    np.testing.assert_allclose(jac[0], num_i, atol=JAC_ATOL)
    np.testing.assert_allclose(jac[1], num_j, atol=JAC_ATOL)
    np.testing.assert_allclose(jac[2], num_c, atol=JAC_ATOL)


def test_gtsam_linear_equals_handrolled_with_covariance():
    rng = np.random.default_rng(3)
    u = random_motions(rng, 300)
    ref = u @ X_TRUE.T + rng.normal(0, [2e-3, 2e-3, 1e-3], (300, 3))
    hand, gt = fit_linear(u, ref), fit_linear_gtsam(u, ref)
    assert np.abs(gt.X - hand.X).max() <= 1e-9 * np.abs(hand.X).max()
    np.testing.assert_allclose(gt.covariance, hand.covariance, rtol=1e-6, atol=1e-9 * np.abs(hand.covariance).max())
    assert gt.residuals.sigma2 == pytest.approx(hand.residuals.sigma2, rel=1e-9)
    with pytest.raises(InputError, match=r"X\[\.,2\] \(dtheta column\) is unobservable"):
        fit_linear_gtsam(u * [1, 1, 0], ref)


def test_gtsam_diff_drive_equals_handrolled():
    rng = np.random.default_rng(4)
    s_l = rng.uniform(0.05, 0.3, 200)
    s_r = s_l + rng.normal(0, 0.03, 200)
    from gtvo.wheel_calibration.diff_drive import diff_drive_motions_from_arcs
    odom = diff_drive_motions_from_arcs(s_l, s_r, 0.5)
    ref = diff_drive_motions_from_arcs(1.03 * s_l, 0.98 * s_r, 1.08 * 0.5) + rng.normal(0, 1e-3, (200, 3))
    hand, gt = fit_diff_drive(odom, ref, 0.5), fit_diff_drive_gtsam(odom, ref, 0.5)
    np.testing.assert_allclose(gt.params, hand.params, rtol=1e-9)
    np.testing.assert_allclose(gt.covariance, hand.covariance, rtol=1e-6)


def synthetic_joint_problem(n: int = 200, seed: int = 5):
    rng = np.random.default_rng(seed)
    true_u = random_motions(rng, n)
    gt = integrate_motions(true_u)
    raw = apply_linear(np.linalg.inv(X_TRUE), true_u) + rng.normal(0, [2e-3, 2e-3, 1e-3], (n, 3))
    priors = [PosePrior(i, tuple(gt[i] + rng.normal(0, [0.05, 0.05, 0.02])), (0.05, 0.05, 0.02))
              for i in range(0, n + 1, 10)]
    closures = []
    for i, j in [(5, 120), (40, 190), (77, 160)]:
        rel = gtsam.Pose2(*gt[i]).between(gtsam.Pose2(*gt[j]))
        closures.append(LoopClosure(i, j, (rel.x(), rel.y(), rel.theta()), (0.02, 0.02, 0.01)))
    return raw, gt, priors, closures


def test_joint_calibration_recovers_x_and_improves_trajectory():
    raw, gt, priors, closures = synthetic_joint_problem()
    sig = (2e-3, 2e-3, 1e-3)
    joint = joint_calibration(raw, sig, priors, closures)
    uncal = joint_calibration(raw, sig, priors, closures, calibrate=False)
    se = np.sqrt(np.diag(joint.covariance)).reshape(3, 3)
    err = np.abs(joint.X - X_TRUE)
    # stated tolerance: every entry within 4 marginal standard deviations, and 0.05 absolute
    assert np.all(err < 4 * se), (err, se)
    assert err.max() < 0.05
    ate_joint = position_rmse(joint.poses, gt, align=False)
    ate_uncal = position_rmse(uncal.poses, gt, align=False)
    ate_dead_raw = position_rmse(integrate_motions(raw, gt[0]), gt, align=False)
    ate_dead_cal = position_rmse(integrate_motions(apply_linear(joint.X, raw), gt[0]), gt, align=False)
    assert ate_joint < 0.5 * ate_uncal
    assert ate_dead_cal < 0.5 * ate_dead_raw
    assert position_rmse(joint.poses, gt) <= ate_joint + 1e-12  # alignment can only help


def test_joint_calibration_bad_input():
    raw, _, priors, _ = synthetic_joint_problem()
    with pytest.raises(InputError, match="at least one absolute pose prior"):
        joint_calibration(raw, (1e-3, 1e-3, 1e-3), [])
    with pytest.raises(InputError, match="pose prior index 999"):
        joint_calibration(raw, (1e-3, 1e-3, 1e-3), [PosePrior(999, (0, 0, 0), (1, 1, 1))])
    # one absolute pose cannot fix X (scale and skew of the motions are free)
    with pytest.raises(InputError, match="indeterminate system"):
        joint_calibration(raw, (1e-3, 1e-3, 1e-3), priors[:1])


# ---------------------------------------------------------------- CLI

@pytest.fixture()
def only_this_command():
    """The full ``gtvo`` CLI (every command registered)."""


def test_cli_json_and_plot(tmp_path, capsys, only_this_command):
    rng = np.random.default_rng(6)
    u = random_motions(rng, 100)
    ref = u @ X_TRUE.T
    np.savetxt(tmp_path / "odom.txt", u, header="dx dy dtheta")
    np.savetxt(tmp_path / "ref.txt", ref)
    png = tmp_path / "out" / "traj.png"
    rc = gtvo.cli.main(["calibrate-odometry", str(tmp_path / "odom.txt"), str(tmp_path / "ref.txt"), "--json",
                        "--plot", str(png)])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "linear"
    np.testing.assert_allclose(np.array(out["X"]), X_TRUE, atol=1e-9)
    assert np.array(out["covariance"]).shape == (9, 9)
    assert set(out["residuals"]["rms"]) == {"dx", "dy", "dtheta"}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rc = gtvo.cli.main(["calibrate-odometry", str(tmp_path / "odom.txt"), str(tmp_path / "ref.txt"), "--json",
                        "--model", "diff-drive", "--solver", "gtsam", "--baseline", "0.5"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["model"] == "diff-drive" and out["solver"] == "gtsam" and len(out["covariance"]) == 3


def test_cli_bad_file_exit_code_2(tmp_path, capsys, only_this_command):
    (tmp_path / "odom.txt").write_text("0.1 0 0\n0.2 0 oops\n")
    (tmp_path / "ref.txt").write_text("0.1 0 0\n0.2 0 0\n")
    rc = gtvo.cli.main(["calibrate-odometry", str(tmp_path / "odom.txt"), str(tmp_path / "ref.txt"), "--json"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "odom.txt:2" in err and "Traceback" not in err
    (tmp_path / "odom.txt").write_text("".join(f"{0.1 + i * 0.01} 0.0 0\n" for i in range(10)))
    (tmp_path / "ref.txt").write_text("".join(f"{0.1 + i * 0.01} 0.0 0\n" for i in range(10)))
    assert gtvo.cli.main(["calibrate-odometry", str(tmp_path / "odom.txt"), str(tmp_path / "ref.txt")]) == 2
    assert "unobservable" in capsys.readouterr().err


@pytest.mark.realdata
def test_real_data_gtsam_matches_readme(shared_data):
    d = shared_data / "odometry_calibration" / "robot_mapping_odom_calib"
    odom, ref = np.loadtxt(d / "odom_motions"), np.loadtxt(d / "scanmatched_motions")
    hand, gt = fit_linear(odom, ref), fit_linear_gtsam(odom, ref)
    assert np.abs(gt.X - hand.X).max() <= 1e-9 * np.abs(hand.X).max()
    np.testing.assert_allclose(gt.covariance, hand.covariance, rtol=1e-6, atol=1e-12)
