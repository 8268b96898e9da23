"""Odometry calibration: the notes' linear least squares, diff-drive model, degenerate input, readers."""

from __future__ import annotations

import numpy as np
import pytest

from gtvo.wheel_calibration import (fit_diff_drive, fit_linear, integrate_motions, position_rmse, read_motion_pair,
                              read_motions, relative_motions)
from factors.odometry_calibration import arc_coefficients, diff_drive_motion_scalar, wheel_arcs
from gtvo.wheel_calibration.diff_drive import apply_diff_drive, diff_drive_motions_from_arcs
from gtvo.wheel_calibration.linear import linear_errors, linear_jacobians, normal_equations
from gtvo.errors import InputError

X_TRUE = np.array([[1.04, 0.08, -0.03], [0.02, 0.93, 0.05], [0.006, -0.04, 0.91]])
README_X = np.array([[1.00185, 4.686154, -0.468625], [0.007172, 0.445732, 0.052008], [0.004872, -1.95554, 1.218938]])


def random_motions(rng: np.random.Generator, n: int) -> np.ndarray:
    return np.column_stack([rng.uniform(0.05, 0.5, n), rng.normal(0, 0.05, n), rng.normal(0, 0.1, n)])


def test_closed_form_matches_numpy_lstsq_and_recovers_x():
    rng = np.random.default_rng(0)
    u = random_motions(rng, 400)
    ref = u @ X_TRUE.T + rng.normal(0, 1e-3, (400, 3))
    fit = fit_linear(u, ref)
    x_lstsq = np.linalg.lstsq(u, ref, rcond=None)[0].T
    np.testing.assert_allclose(fit.X, x_lstsq, rtol=0, atol=1e-12)
    assert np.abs(fit.X - X_TRUE).max() < 0.05
    # residual statistics and covariance = sigma^2 H^-1, sigma^2 = RSS / (3N - 9)
    e = ref - u @ fit.X.T
    assert fit.residuals.rss == pytest.approx(np.sum(e ** 2), rel=1e-12)
    assert fit.residuals.dof == 3 * 400 - 9
    np.testing.assert_allclose(fit.residuals.rms, np.sqrt(np.mean(e ** 2, axis=0)), rtol=1e-12)
    cov_rows = fit.residuals.sigma2 * np.linalg.inv(u.T @ u)
    np.testing.assert_allclose(fit.covariance, np.kron(np.eye(3), cov_rows), rtol=1e-9, atol=1e-18)
    assert fit.residuals.sigma2 == pytest.approx(1e-6, rel=0.15)  # recovers the simulated noise variance


def test_linear_jacobian_matches_numeric():
    rng = np.random.default_rng(1)
    u, ref = random_motions(rng, 5), random_motions(rng, 5)
    x = X_TRUE.ravel()
    eps = 1e-6
    num = np.stack([(linear_errors(x + eps * d, u, ref) - linear_errors(x - eps * d, u, ref)) / (2 * eps)
                    for d in np.eye(9)], axis=2)
    np.testing.assert_allclose(linear_jacobians(u), num, atol=1e-9)
    h, b = normal_equations(x, u, ref)
    np.testing.assert_allclose(h, np.kron(np.eye(3), u.T @ u), atol=1e-12)


def test_integrate_and_relative_motions_are_inverse():
    rng = np.random.default_rng(2)
    u = random_motions(rng, 50)
    u[:, 2] *= 10  # wrap around
    np.testing.assert_allclose(relative_motions(integrate_motions(u)), np.column_stack([u[:, :2], (u[:, 2] + np.pi) % (2 * np.pi) - np.pi]), atol=1e-12)


# ---------------------------------------------------------------- degenerate input

def test_straight_line_only_names_dtheta_column():
    rng = np.random.default_rng(3)
    u = random_motions(rng, 100)
    u[:, 2] = 0.0
    with pytest.raises(InputError, match=r"X\[\.,2\] \(dtheta column\) is unobservable.*all dtheta are zero"):
        fit_linear(u, u)


def test_collinear_columns_named_as_combination():
    rng = np.random.default_rng(4)
    u = random_motions(rng, 100)
    u[:, 1] = 0.5 * u[:, 0]
    with pytest.raises(InputError, match=r"combination .*X\[\.,0\].*X\[\.,1\].* is unobservable"):
        fit_linear(u, u)


def test_too_few_motions_and_nan_and_mismatch():
    rng = np.random.default_rng(5)
    u = random_motions(rng, 3)
    with pytest.raises(InputError, match="too few motions: 3"):
        fit_linear(u, u)
    u = random_motions(rng, 20)
    bad = u.copy()
    bad[7, 1] = np.nan
    with pytest.raises(InputError, match="row 7 is not finite"):
        fit_linear(bad, u)
    with pytest.raises(InputError, match="20 motions but the reference has 19"):
        fit_linear(u, u[:19])


def test_diff_drive_straight_line_names_baseline():
    s = np.linspace(0.1, 0.3, 50)
    u = diff_drive_motions_from_arcs(s, s, 0.5)
    with pytest.raises(InputError, match="baseline scale k_b is unobservable.*all dtheta are zero"):
        fit_diff_drive(u, u, 0.5)


def test_diff_drive_turning_on_the_spot_names_wheel_combination():
    t = np.linspace(0.1, 0.3, 50)
    u = np.column_stack([0 * t, 0 * t, t])
    with pytest.raises(InputError, match="unobservable"):
        fit_diff_drive(u, u, 0.5)


# ---------------------------------------------------------------- differential drive

def test_arc_coefficients_series_and_derivatives():
    t = np.array([-0.7, -0.0500001, -0.0499999, -1e-3, 0.0, 1e-7, 0.02, 0.0499999, 0.0500001, 1.3])
    a, b, da, db = arc_coefficients(t)
    big = np.abs(t) > 1e-2  # where the closed forms are accurate references
    np.testing.assert_allclose(a[big], np.sin(t[big]) / t[big], rtol=1e-12)
    np.testing.assert_allclose(b[big], (1 - np.cos(t[big])) / t[big], rtol=1e-11)
    assert a[t == 0] == 1.0 and b[t == 0] == 0.0 and db[t == 0] == 0.5
    eps = 1e-6
    ap, bp, _, _ = arc_coefficients(t + eps)
    am, bm, _, _ = arc_coefficients(t - eps)
    np.testing.assert_allclose(da, (ap - am) / (2 * eps), atol=1e-9)
    np.testing.assert_allclose(db, (bp - bm) / (2 * eps), atol=1e-9)


def synthetic_diff_drive(rng, n, params, b0, noise=0.0):
    s_l = rng.uniform(0.05, 0.3, n)
    s_r = s_l + rng.normal(0, 0.03, n)
    odom = diff_drive_motions_from_arcs(s_l, s_r, b0)
    ref = diff_drive_motions_from_arcs(params[0] * s_l, params[1] * s_r, params[2] * b0)
    return odom, ref + rng.normal(0, noise, ref.shape)


def test_diff_drive_wheel_arcs_roundtrip_and_jacobian():
    rng = np.random.default_rng(6)
    b0 = 0.4
    s_l = rng.uniform(-0.3, 0.3, 30)
    s_r = rng.uniform(-0.3, 0.3, 30)
    u = diff_drive_motions_from_arcs(s_l, s_r, b0)
    sl2, sr2 = wheel_arcs(u, b0)
    np.testing.assert_allclose(sl2, s_l, atol=1e-12)
    np.testing.assert_allclose(sr2, s_r, atol=1e-12)
    p = np.array([1.02, 0.97, 1.1])
    _, jac = apply_diff_drive(p, u, b0, with_jacobian=True)
    eps = 1e-6
    num = np.stack([(apply_diff_drive(p + eps * d, u, b0) - apply_diff_drive(p - eps * d, u, b0)) / (2 * eps)
                    for d in np.eye(3)], axis=2)
    np.testing.assert_allclose(jac, num, atol=1e-9)
    # the one-motion path used by the GTSAM factor is the same math
    for k in range(len(u)):
        f1, j1 = diff_drive_motion_scalar(p, sl2[k], sr2[k], b0)
        np.testing.assert_allclose(f1, apply_diff_drive(p, u[k:k + 1], b0)[0], rtol=0, atol=1e-14)
        np.testing.assert_allclose(j1, jac[k], rtol=0, atol=1e-13)


def test_diff_drive_recovers_known_parameters():
    rng = np.random.default_rng(7)
    p_true = np.array([1.03, 0.98, 1.08])
    odom, ref = synthetic_diff_drive(rng, 300, p_true, 0.5)
    fit = fit_diff_drive(odom, ref, 0.5)
    np.testing.assert_allclose(fit.params, p_true, atol=1e-10)  # noise-free: exact
    odom, ref = synthetic_diff_drive(rng, 300, p_true, 0.5, noise=1e-3)
    fit = fit_diff_drive(odom, ref, 0.5)
    se = np.sqrt(np.diag(fit.covariance))
    assert np.all(np.abs(fit.params - p_true) < 5 * se)
    assert fit.baseline == pytest.approx(0.5 * fit.params[2])


# ---------------------------------------------------------------- readers

def test_reader_plain_table_and_errors(tmp_path):
    good = tmp_path / "odom.txt"
    good.write_text("# dx dy dtheta\n0.1 0 0.01\n\n0.2 0.001 -0.02  # comment\n")
    np.testing.assert_allclose(read_motions(good), [[0.1, 0, 0.01], [0.2, 0.001, -0.02]])
    cases = {"short.txt": ("0.1 0 0\n0.1 0\n", r"short.txt:2: expected 3 numbers"),
             "word.txt": ("0.1 0 0\n0.1 abc 0\n", r"word.txt:2: not a number"),
             "nan.txt": ("0.1 0 0\n0.1 0 0\nnan 0 0\n", r"nan.txt:3: non-finite"),
             "empty.txt": ("# only a header\n", r"empty.txt: no motions"),
             "hdr.txt": ("# rows: 5\n# columns: 3\n0.1 0 0\n", r"hdr.txt: header says rows: 5")}
    for name, (text, pattern) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputError, match=pattern):
            read_motions(tmp_path / name)
    with pytest.raises(InputError, match="motions file not found"):
        read_motions(tmp_path / "missing.txt")
    other = tmp_path / "ref.txt"
    other.write_text("0.1 0 0\n")
    with pytest.raises(InputError, match="2 odometry motions but 1 reference"):
        read_motion_pair(good, other)


# ---------------------------------------------------------------- real data

@pytest.mark.realdata
def test_real_data_matches_readme(shared_data):
    d = shared_data / "odometry_calibration" / "robot_mapping_odom_calib"
    odom, ref = read_motion_pair(d / "odom_motions", d / "scanmatched_motions")
    assert odom.shape == (2000, 3)
    fit = fit_linear(odom, ref)
    np.testing.assert_allclose(fit.X, README_X, atol=1e-5)
    assert np.linalg.det(fit.X) == pytest.approx(0.614026, abs=1e-5)
    # per motion the scan-matching noise dominates (RSS 0.80 raw vs 0.79 calibrated), but the
    # systematic part accumulates: the integrated trajectory must come much closer to the reference
    reference_path = integrate_motions(ref)
    raw_err = position_rmse(integrate_motions(odom), reference_path, align=False)
    assert position_rmse(integrate_motions(fit.apply(odom)), reference_path, align=False) < 0.25 * raw_err
    dd = fit_diff_drive(odom, ref, 0.5)
    assert position_rmse(integrate_motions(dd.apply(odom)), reference_path, align=False) < 0.25 * raw_err
    assert dd.residuals.rss < 1.01 * fit.residuals.rss  # 3 physical parameters fit about as well as 9


def test_calibrate_dispatch_and_unknown_model():
    from gtvo.wheel_calibration import calibrate
    rng = np.random.default_rng(8)
    u = random_motions(rng, 50)
    ref = u @ X_TRUE.T
    np.testing.assert_allclose(calibrate(u, ref).X, X_TRUE, atol=1e-10)
    assert calibrate(u, ref, "diff-drive", nominal_baseline=0.5).to_dict()["model"] == "diff-drive"
    with pytest.raises(InputError, match="unknown model/solver 'tricycle'"):
        calibrate(u, ref, "tricycle")
