"""Every analytic Jacobian of every factor against central differences through gtsam retract.

Images are analytic (smooth sinusoids, exact gradients), so the only error is the finite
difference itself: with h = 1e-6 the tolerance is 1e-6 relative to the largest entry of the
compared block (measured: about 1e-9).
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.gtsam_factors import PhotometricBatchFactor, PhotometricFactor, StereoFactor
from gtvo.core.keys import affine_key as A
from gtvo.core.keys import inverse_depth_key as D
from gtvo.core.keys import pose_key as X
from gtvo.core.keys import right_affine_key as RA
from factors.photometric import PATTERN_DSO8, photometric_residuals, sample_host
from factors.smoothness import (ConstantVelocityFactor, InverseDepthSmoothnessFactor, MotionSmoothnessFactor,
                                edge_aware_weight)
from factors.weights import huber_loss, variance_weight
from gtvo.errors import InputError
from tests._factors_synthetic import SinusoidImage, numeric_jacobians, small_camera

REL_TOL = 1e-6


def rand_pose(rng, rot=0.05, trans=0.1, base=None):
    T = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, rot, 3)), rng.normal(0, trans, 3))
    return T if base is None else base.compose(T)


def assert_close(analytic, numeric, tol=REL_TOL):
    scale = max(np.abs(numeric).max(), 1e-12)
    err = np.abs(np.asarray(analytic) - numeric).max() / scale
    assert err < tol, f"relative Jacobian error {err:.3g} > {tol}"


def evaluate(factor, values):
    H = [None] * factor.size()
    e = factor._evaluate(factor, values, H)
    return e, H


@pytest.mark.parametrize("seed", range(12))
def test_kernel_jacobians_random_configurations(seed):
    rng = np.random.default_rng(seed)
    cam = small_camera()
    host, tgt = SinusoidImage(seed=seed + 100), SinusoidImage(seed=seed + 200)
    n = 30
    px = np.c_[rng.uniform(25, 135, n), rng.uniform(25, 95, n)]
    d = rng.uniform(0.1, 2.0, n)
    Th = rand_pose(rng)
    Tt = rand_pose(rng, 0.02, 0.05, Th)
    ah, at = rng.normal(0, 0.2, 2), rng.normal(0, 0.2, 2)
    Ih, hv = sample_host(host, px)
    L = photometric_residuals(cam, Ih, hv, px, d, Th, Tt, tgt, ah, at)
    assert L.valid.mean() > 0.9

    def res(Th_=Th, Tt_=Tt, d_=d, ah_=ah, at_=at):
        return photometric_residuals(cam, Ih, hv, px, d_, Th_, Tt_, tgt, ah_, at_, jacobians=False).residual

    h = 1e-6
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        assert_close(L.J_host[..., k], (res(Th_=Th.retract(xi)) - res(Th_=Th.retract(-xi))) / (2 * h))
        assert_close(L.J_target[..., k], (res(Tt_=Tt.retract(xi)) - res(Tt_=Tt.retract(-xi))) / (2 * h))
    assert_close(L.J_depth, (res(d_=d + h) - res(d_=d - h)) / (2 * h))
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        assert_close(L.J_affine_host[..., k], (res(ah_=ah + e) - res(ah_=ah - e)) / (2 * h))
        assert_close(L.J_affine_target[..., k], (res(at_=at + e) - res(at_=at - e)) / (2 * h))


def photometric_setup(seed, variance=0.0, huber_k=None):
    rng = np.random.default_rng(seed)
    cam = small_camera()
    host, tgt = SinusoidImage(seed=seed + 1), SinusoidImage(seed=seed + 2)
    Th = rand_pose(rng)
    Tt = rand_pose(rng, 0.02, 0.05, Th)
    px = np.array([rng.uniform(30, 130), rng.uniform(30, 90)])
    f = PhotometricFactor(X(0), X(1), D(0), cam, px, host, tgt, inverse_depth_variance=variance,
                          huber_k=huber_k, affine_host_key=A(0), affine_target_key=A(1))
    v = gtsam.Values()
    v.insert(X(0), Th)
    v.insert(X(1), Tt)
    v.insert(D(0), float(rng.uniform(0.2, 1.5)))
    v.insert(A(0), rng.normal(0, 0.2, 2))
    v.insert(A(1), rng.normal(0, 0.2, 2))
    return f, v


@pytest.mark.parametrize("seed", range(10))
def test_photometric_factor_jacobians_constant_weight(seed):
    f, v = photometric_setup(seed)
    e, H = evaluate(f, v)
    num = numeric_jacobians(lambda vv: evaluate(f, vv)[0], v, list(f.keys()))
    assert len(H) == 5
    for Ha, Hn in zip(H, num):
        assert Ha.shape == Hn.shape
        assert_close(Ha, Hn)


@pytest.mark.parametrize("seed", range(5))
def test_photometric_factor_variance_weight_is_frozen_in_jacobian(seed):
    """With V > 0 the whitening sqrt(W) depends on the state; H = sqrt(W(x)) dr/dx by design."""
    f, v = photometric_setup(seed, variance=0.05)
    e, H = evaluate(f, v)
    f0, _ = photometric_setup(seed, variance=0.0)
    e0, _ = evaluate(f0, v)
    r = e0 * np.sqrt(2 * f0.sigma ** 2)  # raw residual
    _, H0 = evaluate(f0, v)
    Hraw = [h * np.sqrt(2 * f0.sigma ** 2) for h in H0]
    Jd = Hraw[2][:, 0]
    s = np.sqrt(variance_weight(Jd[None], np.array([0.05]), f.sigma))[0]
    np.testing.assert_allclose(e, s * r, rtol=1e-12, atol=1e-12)
    for Ha, Hr in zip(H, Hraw):
        np.testing.assert_allclose(Ha, s[:, None] * Hr, rtol=1e-12, atol=1e-12)
    assert np.all(s < 1 / np.sqrt(2 * f.sigma ** 2) + 1e-15)


def test_photometric_factor_linearize_through_gtsam_matches():
    f, v = photometric_setup(3)
    e, H = evaluate(f, v)
    gf = f.linearize(v)
    A_, b = gf.jacobian()
    np.testing.assert_allclose(A_, np.hstack(H), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(b, -e, rtol=1e-10, atol=1e-10)
    assert f.error(v) == pytest.approx(0.5 * e @ e)


@pytest.mark.parametrize("seed", range(6))
def test_stereo_factor_jacobians(seed):
    rng = np.random.default_rng(seed)
    cam = small_camera()
    left, right = SinusoidImage(seed=seed + 10), SinusoidImage(seed=seed + 20)
    b = 0.5
    f = StereoFactor(D(0), RA(0), cam, b, [rng.uniform(60, 130), rng.uniform(30, 90)], left, right,
                     lambda_stereo=2.0, huber_k=None, left_affine_key=A(0))
    v = gtsam.Values()
    v.insert(D(0), float(rng.uniform(0.1, 0.5)))
    v.insert(RA(0), rng.normal(0, 0.2, 2))
    v.insert(A(0), rng.normal(0, 0.2, 2))
    e, H = evaluate(f, v)
    num = numeric_jacobians(lambda vv: evaluate(f, vv)[0], v, list(f.keys()))
    for Ha, Hn in zip(H, num):
        assert_close(Ha, Hn)
    # dp'/dd = (-fx b, 0): dr/dd = -fx b gx_R (whitened by sqrt(lambda W))
    d = v.atDouble(D(0))
    pp = f.pixel + PATTERN_DSO8
    vals, _ = right.sample(pp[:, 0] - cam.fx * b * d, pp[:, 1])
    np.testing.assert_allclose(H[0][:, 0], np.sqrt(2.0 / (2 * f.sigma ** 2)) * (-cam.fx * b * vals[:, 1]),
                               rtol=1e-10)


def test_smoothness_factor_and_edge_weight():
    f = InverseDepthSmoothnessFactor(D(0), D(1), sigma_d=0.02, weight=0.5, huber_k=None)
    v = gtsam.Values()
    v.insert(D(0), 0.3)
    v.insert(D(1), 0.35)
    e, H = evaluate(f, v)
    assert e[0] == pytest.approx(np.sqrt(0.5) * 0.05 / 0.02)
    for Ha, Hn in zip(H, numeric_jacobians(lambda vv: evaluate(f, vv)[0], v, [D(0), D(1)])):
        assert_close(Ha, Hn)
    w = edge_aware_weight([100, 100], [101, 160], edge_scale=10)
    assert w[0] > 0.99 and w[1] < 1e-10


def _check_three_pose_factor(f, rng):
    """Random poses x0, x1, x2 in a Values; ``f``'s Jacobians there against central differences."""
    T0 = rand_pose(rng, 0.5, 2.0)
    T1 = rand_pose(rng, 0.2, 1.0, T0)
    T2 = rand_pose(rng, 0.2, 1.0, T1)
    v = gtsam.Values()
    for i, T in enumerate((T0, T1, T2)):
        v.insert(X(i), T)
    _, H = evaluate(f, v)
    for Ha, Hn in zip(H, numeric_jacobians(lambda vv: evaluate(f, vv)[0], v, [X(0), X(1), X(2)])):
        assert_close(Ha, Hn, 1e-6)
    return v, (T0, T1, T2)


@pytest.mark.parametrize("seed", range(10))
def test_motion_smoothness_jacobians(seed):
    rng = np.random.default_rng(seed)
    f = MotionSmoothnessFactor(X(0), X(1), X(2), 0.01, 0.05)
    v, (T0, T1, T2) = _check_three_pose_factor(f, rng)
    # constant velocity -> zero residual
    v.update(X(2), T1.compose(T0.between(T1)))
    assert np.abs(evaluate(f, v)[0]).max() < 1e-9


@pytest.mark.parametrize("seed", range(10))
def test_constant_velocity_jacobians_and_irregular_times(seed):
    rng = np.random.default_rng(seed)
    dt_prev, dt_next = rng.uniform(0.05, 0.5, 2)
    f = ConstantVelocityFactor(X(0), X(1), X(2), dt_prev, dt_next, 0.5, [1.0, 2.0, 3.0])
    v, (T0, T1, T2) = _check_three_pose_factor(f, rng)
    e, _ = evaluate(f, v)
    # whitened by the acceleration sigmas times the time between the two velocity estimates
    tau = 0.5 * (dt_prev + dt_next)
    raw = gtsam.Pose3.Logmap(T1.between(T2)) / dt_next - gtsam.Pose3.Logmap(T0.between(T1)) / dt_prev
    np.testing.assert_allclose(e, raw, rtol=1e-9)
    sigmas = np.array([0.5, 0.5, 0.5, 1.0, 2.0, 3.0]) * tau
    assert f.error(v) == pytest.approx(0.5 * np.sum((raw / sigmas) ** 2), rel=1e-9)
    # a constant body twist at irregular times -> zero residual
    xi = rng.normal(0, 0.5, 6)
    v.update(X(1), T0.compose(gtsam.Pose3.Expmap(xi * dt_prev)))
    v.update(X(2), T0.compose(gtsam.Pose3.Expmap(xi * (dt_prev + dt_next))))
    assert np.abs(evaluate(f, v)[0]).max() < 1e-9
    with pytest.raises(InputError):
        ConstantVelocityFactor(X(0), X(1), X(2), 0.0, 0.1)
    with pytest.raises(InputError):
        ConstantVelocityFactor(X(0), X(1), X(2), 0.1, 0.1, -1.0)


@pytest.mark.parametrize("with_host", [False, True])
def test_batch_factor_jacobians_and_robust_cost(with_host):
    rng = np.random.default_rng(7)
    cam = small_camera()
    host, tgt = SinusoidImage(seed=31), SinusoidImage(seed=32)
    n = 40
    px = np.c_[rng.uniform(25, 135, n), rng.uniform(25, 95, n)]
    d = rng.uniform(0.2, 1.5, n)
    Th = rand_pose(rng)
    Tt = rand_pose(rng, 0.02, 0.05, Th)
    kw = dict(host_key=X(0) if with_host else None, T_world_host=Th, affine_host_key=A(0), affine_target_key=A(1))
    f = PhotometricBatchFactor(X(1), cam, px, d, host, tgt, huber_k=None, **kw)
    v = gtsam.Values()
    v.insert(X(1), Tt)
    v.insert(A(0), rng.normal(0, 0.2, 2))
    v.insert(A(1), rng.normal(0, 0.2, 2))
    if with_host:
        v.insert(X(0), Th)
    e, H = evaluate(f, v)
    for Ha, Hn in zip(H, numeric_jacobians(lambda vv: evaluate(f, vv)[0], v, list(f.keys()))):
        assert_close(Ha, Hn)
    # Huber: 0.5 |error|^2 is the robust cost and the gradient is the IRLS gradient
    k = 1.0
    fr = PhotometricBatchFactor(X(1), cam, px, d, host, tgt, huber_k=k, **kw)
    er, Hr = evaluate(fr, v)
    P = PATTERN_DSO8.shape[0]
    e_n = e[:-1].reshape(n, P)
    norms = np.linalg.norm(e_n, axis=1)
    assert (norms > k).sum() > 5
    assert fr.error(v) == pytest.approx(huber_loss(norms, k).sum(), rel=1e-12)
    w = np.where(norms <= k, 1.0, k / norms)
    g_irls = np.hstack(H)[:-1].T @ (np.repeat(w, P) * e[:-1])
    np.testing.assert_allclose(np.hstack(Hr).T @ er, g_irls, rtol=1e-10, atol=1e-10)


def test_matrix_cost_of_JtWJ_analytic_vs_numeric():
    """The notes' eq. (4.1): cost = sum (A(i,j) - B(i,j))^2, A, B = J^T W J analytic / numeric."""
    rng = np.random.default_rng(11)
    cam = small_camera()
    host, tgt = SinusoidImage(seed=41), SinusoidImage(seed=42)
    n = 200
    px = np.c_[rng.uniform(25, 135, n), rng.uniform(25, 95, n)]
    d = rng.uniform(0.2, 1.5, n)
    V = rng.uniform(0, 0.01, n)
    Th, Tt = gtsam.Pose3(), rand_pose(rng, 0.02, 0.05)
    Ih, hv = sample_host(host, px)
    L = photometric_residuals(cam, Ih, hv, px, d, Th, Tt, tgt)
    W = variance_weight(L.J_depth, V, 4.0)
    Ja = L.J_target.reshape(-1, 6)
    h = 1e-6
    cols = []
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        rp = photometric_residuals(cam, Ih, hv, px, d, Th, Tt.retract(xi), tgt, jacobians=False).residual
        rm = photometric_residuals(cam, Ih, hv, px, d, Th, Tt.retract(-xi), tgt, jacobians=False).residual
        cols.append(((rp - rm) / (2 * h)).reshape(-1))
    Jn = np.stack(cols, -1)
    Wf = W.reshape(-1)
    A_ = Ja.T @ (Wf[:, None] * Ja)
    B_ = Jn.T @ (Wf[:, None] * Jn)
    cost = float(np.sum((A_ - B_) ** 2))
    print(f"matrix cost sum (A-B)^2 = {cost:.3e}, relative to sum A^2 = {cost / np.sum(A_ ** 2):.3e}")
    assert cost / np.sum(A_ ** 2) < 1e-12


@pytest.mark.parametrize("seed", range(4))
def test_photometric_factor_fixed_weights_exact_jacobian(seed):
    """With fixed weights (V > 0), the factor's full numerical derivative is its analytic H."""
    f, v = photometric_setup(seed, variance=0.05)
    e, H = evaluate(f, v)
    f0, _ = photometric_setup(seed, variance=0.0)  # W = 1/(2 sigma^2): its H gives the raw dr/dd
    Jd = evaluate(f0, v)[1][2][:, 0] * np.sqrt(2 * f0.sigma ** 2)
    W = variance_weight(Jd[None], np.array([0.05]), f.sigma)[0]
    fixed = PhotometricFactor(X(0), X(1), D(0), f.camera, f.pixel[0], SinusoidImage(seed=seed + 1),
                              SinusoidImage(seed=seed + 2), inverse_depth_variance=0.05, huber_k=None,
                              affine_host_key=A(0), affine_target_key=A(1), weights=W)
    e2, H2 = evaluate(fixed, v)
    np.testing.assert_allclose(e2, e, rtol=1e-12)
    for Ha, Hn in zip(H2, numeric_jacobians(lambda vv: evaluate(fixed, vv)[0], v, list(fixed.keys()))):
        assert_close(Ha, Hn)
