"""The per-host smart factor: its reduced system is the Schur complement of the per-point graph,
its error is the true cost, and GTSAM's LM with it recovers poses and depths."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.gtsam_factors import PhotometricFactor, StereoFactor
from gtvo.core.keys import affine_key as A
from gtvo.core.keys import inverse_depth_key as D
from gtvo.core.keys import pose_key as X
from factors.smart import HostPointsFactor, JacobianBudget
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError
from tests._factors_synthetic import PlaneSceneImage, SinusoidImage, small_camera



def per_point_graph(cam, px, d, V, host, targets, huber_k, affine, right=None, baseline=None, lam=1.0,
                    stereo_affine=(0.0, 0.0)):
    g = gtsam.NonlinearFactorGraph()
    for j in range(len(d)):
        g.add(gtsam.PriorFactorDouble(D(j), d[j], gtsam.noiseModel.Isotropic.Sigma(1, np.sqrt(V[j]))))
        if right is not None:
            g.add(StereoFactor(D(j), None, cam, baseline, px[j], host, right, lam, V[j], huber_k=huber_k,
                               affine_right=stereo_affine))
        for t, img in enumerate(targets):
            g.add(PhotometricFactor(X(0), X(1 + t), D(j), cam, px[j], host, img, V[j], huber_k=huber_k,
                                    affine_host_key=A(0) if affine else None,
                                    affine_target_key=A(1 + t) if affine else None))
    return g


@pytest.mark.parametrize("seed,stereo", [(0, False), (1, False), (2, True), (3, True)])
def test_reduced_system_is_schur_complement_of_per_point_graph(seed, stereo):
    """Relative agreement 1e-8 (measured 1e-10: the 1e-9 eigenvalue floor of the factor)."""
    rng = np.random.default_rng(seed)
    cam = small_camera()
    host, targets = SinusoidImage(seed=seed + 1), [SinusoidImage(seed=seed + 2), SinusoidImage(seed=seed + 3)]
    n = 30
    px = np.c_[rng.uniform(25, 135, n), rng.uniform(25, 95, n)]
    d = rng.uniform(0.2, 1.5, n)
    V = rng.uniform(1e-4, 1e-2, n)
    st = dict(right=SinusoidImage(seed=seed + 4), baseline=0.2, lam=0.7, stereo_affine=(0.05, 2.0)) if stereo else {}
    f = HostPointsFactor(X(0), [X(1), X(2)], cam, px, d, host, targets, V, huber_k=2.0,
                         affine_host_key=A(0), affine_target_keys=[A(1), A(2)],
                         right_image=st.get("right"), baseline=st.get("baseline"), lambda_stereo=st.get("lam", 1.0),
                         stereo_affine=st.get("stereo_affine", (0.0, 0.0)))
    v = gtsam.Values()
    for i in range(3):
        v.insert(X(i), gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.02, 3)), rng.normal(0, 0.05, 3)))
        v.insert(A(i), rng.normal(0, 0.1, 2))
    g = per_point_graph(cam, px, d, V, host, targets, 2.0, True, **st)
    vf = gtsam.Values(v)
    for j in range(n):
        vf.insert(D(j), d[j])
    assert f.error(v) == pytest.approx(g.error(vf), rel=1e-12)
    H = [None] * f.size()
    e = f._evaluate(f, v, H)
    R, er = np.hstack(H)[:-1], e[:-1]
    order = gtsam.Ordering()
    for k in [X(0), X(1), X(2), A(0), A(1), A(2)] + [D(j) for j in range(n)]:
        order.push_back(k)
    Af, b = g.linearize(vf).jacobian(order)
    Hf, gf = Af.T @ Af, -Af.T @ b
    M = 24
    Hs = Hf[:M, :M] - Hf[:M, M:] @ np.linalg.solve(Hf[M:, M:], Hf[M:, :M])
    gs = gf[:M] - Hf[:M, M:] @ np.linalg.solve(Hf[M:, M:], gf[M:])
    assert np.abs(R.T @ R - Hs).max() < 1e-8 * np.abs(Hs).max()
    assert np.abs(R.T @ er - gs).max() < 1e-8 * np.abs(gs).max()
    # the linear model at dx = 0 is the full Gauss-Newton model with the depths at their optimum
    model0 = g.error(vf) - 0.5 * gf[M:] @ np.linalg.solve(Hf[M:, M:], gf[M:])
    assert 0.5 * e @ e == pytest.approx(model0, rel=1e-9)


def plane_problem(n=150, seed=0):
    cam = PinholeCamera(250.0, 250.0, 159.5, 119.5, 320, 240)
    T1 = gtsam.Pose3(gtsam.Rot3.Expmap(np.array([0.01, -0.01, 0.01])), np.array([0.1, -0.02, 0.1]))
    T2 = gtsam.Pose3(gtsam.Rot3.Expmap(np.array([0.02, -0.015, 0.0])), np.array([0.2, -0.05, 0.2]))
    imgs = [PlaneSceneImage(cam, T.matrix(), plane_z=4.0, seed=seed) for T in (gtsam.Pose3(), T1, T2)]
    rng = np.random.default_rng(seed)
    px = np.c_[rng.uniform(30, 290, n), rng.uniform(30, 210, n)]
    d = imgs[0].inverse_depth(px[:, 0], px[:, 1])
    return cam, [gtsam.Pose3(), T1, T2], imgs, px, d, rng


def _perturbed_smart_graph():
    """One smart factor (host + 2 targets, exact rendered plane, depths 3 % off), host pose and
    the first target's translation (the scale gauge) fixed by priors, both targets perturbed:
    ``(factor, graph, initial values, true poses, true depths, initial depths)``."""
    cam, poses, imgs, px, d, rng = plane_problem()
    d0 = d * (1 + 0.03 * rng.normal(size=d.shape))
    f = HostPointsFactor(X(0), [X(1), X(2)], cam, px, d0, imgs[0], imgs[1:], 1e-2, huber_k=3.0, depth_prior=False)
    g = gtsam.NonlinearFactorGraph()
    g.add(f)
    g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-8)))
    g.add(gtsam.PriorFactorPose3(X(1), poses[1], gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, 1.0), np.full(3, 1e-6)])))
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose3())
    v.insert(X(1), poses[1].retract(np.r_[0.005, -0.005, 0.003, 0.0, 0.0, 0.0]))
    v.insert(X(2), poses[2].retract(np.r_[0.004, 0.006, -0.004, 0.02, -0.02, 0.03]))
    return f, g, v, poses, d, d0


def test_lm_with_smart_factor_recovers_poses_and_depths():
    """Exact rendered scene, depths 3 % off, second target perturbed: GTSAM's LM on one smart
    factor recovers poses and depths to 1e-8 (measured 1e-14); the depths follow by back-substitution."""
    f, g, v, poses, d, d0 = _perturbed_smart_graph()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(0.0)
    res = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
    depths = f.commit(res)
    for i in (1, 2):
        assert np.abs(gtsam.Pose3.Logmap(poses[i].between(res.atPose3(X(i))))).max() < 1e-8
    np.testing.assert_allclose(depths, d, rtol=1e-8)
    assert f.cost(res) < 1e-12 * f.cost(v, d0)


def test_smart_factor_rejects_bad_input():
    cam = small_camera()
    img = SinusoidImage()
    with pytest.raises(InputError):
        HostPointsFactor(X(0), [], cam, [[10, 10]], [0.5], img, [])
    with pytest.raises(InputError):
        HostPointsFactor(X(0), [X(1)], cam, [[10, 10]], [-0.5], img, [img])
    with pytest.raises(InputError):
        HostPointsFactor(X(0), [X(1)], cam, [[10, 10]], [0.5], img, [img, img])
    with pytest.raises(InputError):
        HostPointsFactor(X(0), [X(1)], cam, [[10, 10]], [0.5], img, [img], 0.0)


def test_isam2_with_smart_factor_converges():
    """iSAM2 (Gauss-Newton, relinearising every update) on one smart factor: it linearises new
    factors twice at the same point, which must not commit a second depth step."""
    f, g, v, poses, d, d0 = _perturbed_smart_graph()
    params = gtsam.ISAM2Params()
    params.relinearizeSkip = 1
    params.setRelinearizeThreshold(0.0)
    isam = gtsam.ISAM2(params)
    isam.update(g, v)
    for _ in range(7):
        isam.update()
    est = isam.calculateEstimate()
    for i in (1, 2):
        assert np.abs(gtsam.Pose3.Logmap(poses[i].between(est.atPose3(X(i))))).max() < 1e-9
    np.testing.assert_allclose(f.commit(est), d, rtol=1e-9)


def test_whitened_system_factors_the_reduced_system():
    """``R^T R = H + reg I`` and ``R^T e = g`` (Cholesky), also for a singular PSD ``H`` (a host's
    gauge) and, through the eigen fallback, for an ``H`` made indefinite by round-off."""
    from factors.smart import whitened_system  # noqa: PLC0415

    rng = np.random.default_rng(0)
    A = rng.normal(size=(20, 14))
    for H in (A.T @ A, np.pad(A[:, :8].T @ A[:, :8], (0, 6))):
        g = rng.normal(size=H.shape[0])
        R, e = whitened_system(H, g)
        reg = 1e-9 * np.trace(H) / H.shape[0]
        assert np.allclose(R.T @ R, H + reg * np.eye(H.shape[0]), rtol=1e-9, atol=1e-9 * np.abs(H).max())
        assert np.allclose(R.T @ e, g, rtol=1e-8, atol=1e-8)
    H = A.T @ A
    H[0, 0] = -1.0  # indefinite: the eigenvalues are clamped at reg
    R, e = whitened_system(H, np.ones(14))
    assert np.all(np.isfinite(R)) and np.all(np.isfinite(e))
    assert np.all(np.linalg.eigvalsh(R.T @ R) > 0)


@pytest.mark.parametrize("room", [0, 1])
def test_a_jacobian_budget_changes_no_result_and_keeps_what_fits(room):
    """Two host factors under one :class:`JacobianBudget`: with no room neither keeps its cost
    pass's linearisations, with room for one the first keeps them; GTSAM's LM gives bit for bit the
    same poses, depths and cost as without a budget (the linearisation evaluates the state again)."""
    out = []
    for budget in (None, JacobianBudget(0)):
        f, g, v, poses, d, d0 = _perturbed_smart_graph()
        cam, _, imgs, px, _, _ = plane_problem()
        f2 = HostPointsFactor(X(0), [X(2)], cam, px[::2], d0[::2], imgs[0], [imgs[2]], 1e-2, huber_k=3.0,
                              depth_prior=False)
        if budget is not None:
            budget.max_bytes = room * f._jacobian_bytes()
            f._budget = f2._budget = budget
        g.add(f2)
        f.error(v), f2.error(v)
        if budget is not None:
            assert (f._state_lins is not None) == bool(room) and f2._state_lins is None
            assert budget.used == room * f._jacobian_bytes()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(5)
        res = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
        depths = f.commit(res), f2.commit(res)
        if budget is not None:
            assert budget.used == 0  # commit gives it back
        out.append((res, *depths, g.error(res)))
    (a, da, da2, ea), (b, db, db2, eb) = out
    assert ea == eb and np.array_equal(da, db) and np.array_equal(da2, db2)
    for i in (1, 2):
        assert np.array_equal(a.atPose3(X(i)).matrix(), b.atPose3(X(i)).matrix())


def test_a_jacobian_budget_must_not_be_negative():
    with pytest.raises(InputError, match="max_bytes"):
        JacobianBudget(-1)


def test_residuals_kept_at_the_optimum_start_another_factor_without_a_pass(monkeypatch):
    """``kept_residuals`` gives the residuals a factor holds at a state (None elsewhere);
    ``take_residuals`` lets a new factor at that state start from them: its cost and its first
    linearisation are the bits of a factor that evaluated them itself, and it evaluates nothing."""
    import factors.host_points as host_points  # noqa: PLC0415

    f, g, v, poses, d, d0 = _perturbed_smart_graph()
    cam, _, imgs, px, _, _ = plane_problem()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(2)
    res = gtsam.LevenbergMarquardtOptimizer(g, v, params).optimize()
    d1 = f.depths_at(res)
    kept = f.kept_residuals(res, d1)
    assert kept is not None and f.kept_residuals(res, d1 * (1 + 1e-9)) is None and f.kept_residuals(v, d1) is None
    kept_poses, affines, offset, lins = kept
    assert len(kept_poses) == 3 and affines == [] and offset is None

    def fresh():
        return HostPointsFactor(X(0), [X(1), X(2)], cam, px, d1, imgs[0], imgs[1:], 1e-2, huber_k=3.0,
                                depth_prior=False)

    alone, seeded = fresh(), fresh()
    seeded.take_residuals(kept_poses, [], lins)
    e_alone, J_alone = alone.error(res), alone.linearize(res)
    passes = []
    monkeypatch.setattr(host_points.HostPoints, "residuals", lambda *a, **k: passes.append(1))
    e_seeded, J_seeded = seeded.error(res), seeded.linearize(res)
    assert not passes
    assert e_seeded == e_alone
    A1, b1 = J_alone.jacobian()
    A2, b2 = J_seeded.jacobian()
    assert np.array_equal(A1, A2) and np.array_equal(b1, b2)


def test_factors_of_one_shape_share_their_column_blocks():
    cam, _, imgs, px, d, _ = plane_problem()
    one = HostPointsFactor(X(0), [X(1), X(2)], cam, px, d, imgs[0], imgs[1:], 1e-2, affine_host_key=A(0),
                           affine_target_keys=[A(1), A(2)])
    two = HostPointsFactor(X(0), [X(1), X(2)], cam, px[:5], d[:5], imgs[0], imgs[1:], 1e-2, affine_host_key=A(0),
                           affine_target_keys=[A(1), A(2)])
    assert one._column_blocks is two._column_blocks
    assert all(np.array_equal(b, one._columns(t)) for t, b in enumerate(one._column_blocks))
    assert np.array_equal(one._columns(1), np.r_[0:6, 18:20, 12:18, 22:24])
