"""Masks, counts and no-NaN of the kernel; the factors inside a plain GTSAM graph with LM."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.gtsam_factors import PhotometricFactor, StereoFactor
from gtvo.core.keys import affine_key as A
from gtvo.core.keys import inverse_depth_key as D
from gtvo.core.keys import pose_key as X
from factors.photometric import GradientImage, photometric_residuals, sample_host, stereo_residuals
from factors.smoothness import InverseDepthSmoothnessFactor, MotionSmoothnessFactor
from gtvo.core.camera import PinholeCamera
from gtvo.errors import InputError
from tests._factors_synthetic import PlaneSceneImage, SinusoidImage, small_camera



def test_masks_counts_and_no_nan():
    cam = small_camera()
    host, tgt = SinusoidImage(seed=1), SinusoidImage(seed=2)
    px = np.array([[80.0, 60.0], [80.0, 60.0], [80.0, 60.0], [1.0, 1.0], [80.0, 60.0], [80.0, 60.0]])
    d = np.array([0.5, -0.2, 0.0, 0.5, np.nan, 0.5])
    Ih, hv = sample_host(host, px)
    # target 3 m in front of the host along z: points at 2 m (d = 0.5) land behind it
    Tt = gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 3.0]))
    L = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), Tt, tgt)
    assert L.n_bad_depth == 3
    assert L.n_behind == 3 * 8  # points 0, 3, 5 (all pattern pixels)
    assert not L.valid.any()
    for arr in (L.residual, L.J_depth, L.J_host, L.J_target, L.J_affine_host, L.J_affine_target):
        assert np.all(np.isfinite(arr)) and np.all(arr == 0)
    # identity motion: the good points are valid except the one whose host pattern leaves the image
    L = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), gtsam.Pose3(), tgt)
    assert L.valid[[0, 5]].all() and not L.valid[[1, 2, 4]].any()
    assert 0 < L.valid[3].sum() < 8 and L.n_outside == 8 - L.valid[3].sum()
    assert np.all(L.J_target[~L.valid] == 0) and np.all(np.isfinite(L.residual))
    # a large sideways motion: everything outside the target image
    L = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), gtsam.Pose3(gtsam.Rot3(), np.array([50.0, 0, 0])), tgt)
    assert not L.valid.any() and L.n_outside == 3 * 8
    # stereo: a point whose disparity pushes it off the right image
    S = stereo_residuals(cam, 0.5, Ih[:1], hv[:1], px[:1] * [0.1, 1], np.array([2.0]), tgt)
    assert not S.valid.any() and np.all(S.residual == 0)


def test_factor_with_bad_depth_has_zero_error_not_nan():
    cam = small_camera()
    f = PhotometricFactor(X(0), X(1), D(0), cam, [80, 60], SinusoidImage(seed=1), SinusoidImage(seed=2))
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose3())
    v.insert(X(1), gtsam.Pose3())
    v.insert(D(0), -1.0)
    assert f.error(v) == 0.0
    A_, b = f.linearize(v).jacobian()
    assert np.all(A_ == 0) and np.all(b == 0)


def test_gradient_image_rejects_bad_input():
    with pytest.raises(InputError):
        GradientImage(np.zeros((1, 5)))
    img = np.zeros((4, 4))
    img[1, 1] = np.nan
    with pytest.raises(InputError):
        GradientImage(img)
    with pytest.raises(InputError):
        StereoFactor(D(0), None, small_camera(), -0.5, [10, 10], SinusoidImage(), SinusoidImage())
    with pytest.raises(InputError):
        MotionSmoothnessFactor(X(0), X(1), X(2), 0.0, 0.1)


def test_small_graph_lm_recovers_perturbed_pose():
    """Host fixed, 40 points with depth priors: LM on PhotometricFactors recovers the target pose."""
    cam = PinholeCamera(250.0, 250.0, 159.5, 119.5, 320, 240)
    T_true = gtsam.Pose3(gtsam.Rot3.Expmap(np.array([0.01, -0.015, 0.02])), np.array([0.1, -0.05, 0.15]))
    host = PlaneSceneImage(cam, np.eye(4), plane_z=4.0)
    tgt = PlaneSceneImage(cam, T_true.matrix(), plane_z=4.0)
    rng = np.random.default_rng(0)
    px = np.c_[rng.uniform(40, 280, 40), rng.uniform(40, 200, 40)]
    d = host.inverse_depth(px[:, 0], px[:, 1])
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    graph.add(gtsam.NonlinearEqualityPose3(X(0), gtsam.Pose3()) if hasattr(gtsam, "NonlinearEqualityPose3")
              else gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-9)))
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), T_true.retract(np.array([0.01, -0.01, 0.005, 0.03, 0.02, -0.03])))
    values.insert(A(1), np.zeros(2))
    graph.add(gtsam.PriorFactorVector(A(1), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)))
    for j in range(len(d)):
        graph.add(PhotometricFactor(X(0), X(1), D(j), cam, px[j], host, tgt, inverse_depth_variance=1e-4,
                                    affine_target_key=A(1)))
        graph.add(gtsam.PriorFactorDouble(D(j), d[j], gtsam.noiseModel.Isotropic.Sigma(1, 0.01)))
        values.insert(D(j), d[j] * (1 + 0.05 * rng.normal()))
    for j in range(len(d) - 1):
        graph.add(InverseDepthSmoothnessFactor(D(j), D(j + 1), sigma_d=1.0))
    res = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    err = gtsam.Pose3.Logmap(T_true.between(res.atPose3(X(1))))
    assert np.abs(err).max() < 1e-6
    d_est = np.array([res.atDouble(D(j)) for j in range(len(d))])
    np.testing.assert_allclose(d_est, d, rtol=1e-5)
    assert graph.error(res) < 1e-6 * graph.error(values)


def test_motion_smoothness_pulls_middle_pose_to_constant_velocity():
    step = gtsam.Pose3(gtsam.Rot3.Ypr(0.02, 0.0, 0.0), np.array([0.0, 0.0, 1.0]))
    T0 = gtsam.Pose3()
    T2 = step.compose(step)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(X(0), T0, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    graph.add(gtsam.PriorFactorPose3(X(2), T2, gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    graph.add(MotionSmoothnessFactor(X(0), X(1), X(2)))
    v = gtsam.Values()
    v.insert(X(0), T0)
    v.insert(X(1), step.retract(np.array([0.05, -0.02, 0.03, 0.3, -0.2, 0.1])))
    v.insert(X(2), T2)
    res = gtsam.LevenbergMarquardtOptimizer(graph, v).optimize()
    assert np.abs(gtsam.Pose3.Logmap(step.between(res.atPose3(X(1))))).max() < 1e-5


def test_stereo_factor_alone_recovers_inverse_depth():
    """A rendered rectified pair: LM on StereoFactors (depth only) finds the plane's inverse depths."""
    cam = PinholeCamera(250.0, 250.0, 159.5, 119.5, 320, 240)
    b = 0.3
    T_right = np.eye(4)
    T_right[0, 3] = b
    left = PlaneSceneImage(cam, np.eye(4), plane_z=4.0, seed=5)
    right = PlaneSceneImage(cam, T_right, plane_z=4.0, seed=5)
    rng = np.random.default_rng(1)
    px = np.c_[rng.uniform(60, 300, 20), rng.uniform(20, 220, 20)]
    d = left.inverse_depth(px[:, 0], px[:, 1])
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for j in range(len(d)):
        graph.add(StereoFactor(D(j), None, cam, b, px[j], left, right, lambda_stereo=1.0))
        values.insert(D(j), d[j] + 0.01 * rng.normal())  # ~0.75 px disparity error
    res = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    np.testing.assert_allclose([res.atDouble(D(j)) for j in range(len(d))], d, rtol=1e-6)


def test_gradient_image_sample_matches_gtvo_bilinear_sample():
    from gtvo.core.image import bilinear_sample
    rng = np.random.default_rng(0)
    g = GradientImage(rng.uniform(0, 255, (40, 60)))
    u = rng.uniform(-3, 62, (50, 8))
    v = rng.uniform(-3, 42, (50, 8))
    u[0, 0] = np.nan
    v[1, 1] = np.inf
    a, va = g.sample(u, v)
    b, vb = bilinear_sample(g.stack, u, v, border=1.0)
    np.testing.assert_array_equal(va, vb)
    assert 0.2 < va.mean() < 0.95
    np.testing.assert_allclose(a, b, atol=1e-4)  # float32 interpolation weights
    assert np.all(np.isfinite(a)) and np.all(a[~va] == 0)


def test_kernel_rejects_mismatched_input():
    cam = small_camera()
    img = SinusoidImage()
    Ih, hv = sample_host(img, np.array([[50.0, 50.0], [60.0, 60.0]]))
    with pytest.raises(InputError):
        photometric_residuals(cam, Ih, hv, [[50, 50], [60, 60]], [0.5], gtsam.Pose3(), gtsam.Pose3(), img)
    with pytest.raises(InputError):
        photometric_residuals(cam, Ih, hv, [[50, 50], [60, 60]], [0.5, 0.5], np.eye(3), gtsam.Pose3(), img)


def _photometric_graph(target: GradientImage) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values]:
    cam = small_camera()
    graph = gtsam.NonlinearFactorGraph()
    graph.add(PhotometricFactor(X(0), X(1), D(0), cam, [80, 60], SinusoidImage(seed=1), target))
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose3())
    v.insert(X(1), gtsam.Pose3(gtsam.Rot3(), np.array([0.01, 0.0, 0.0])))
    v.insert(D(0), 0.5)
    return graph, v


@pytest.mark.slow
def test_python_factors_are_freed_with_their_graph():
    """GTSAM holds a factor's error function; bound to the factor itself it would form a cycle
    through C++ that Python never frees (with the images: 1 GB per 51 KITTI frames). A factor
    that only a graph holds must still evaluate, and be freed, images included, with the graph."""
    import gc  # noqa: PLC0415
    import weakref  # noqa: PLC0415

    target = GradientImage(np.random.default_rng(0).uniform(0, 255, (120, 160)))
    image_ref = weakref.ref(target)
    graph, v = _photometric_graph(target)
    del target
    gc.collect()
    assert image_ref() is not None  # the graph's factor keeps what its error needs
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(2)
    gtsam.LevenbergMarquardtOptimizer(graph, v, params).optimize()  # called from inside GTSAM
    assert np.isfinite(graph.error(v))
    del graph
    gc.collect()
    assert image_ref() is None


def test_python_factor_attributes_are_shared_with_its_error_function():
    """The error function runs on a twin sharing the factor's attributes: a change made through
    the factor (here fixed weights) is seen by GTSAM's next evaluation."""
    graph, v = _photometric_graph(SinusoidImage(seed=2))
    e0 = graph.error(v)
    assert e0 > 0
    fac = PhotometricFactor(X(0), X(1), D(0), small_camera(), [80, 60], SinusoidImage(seed=1), SinusoidImage(seed=2))
    g2 = gtsam.NonlinearFactorGraph()
    g2.add(fac)
    assert g2.error(v) == pytest.approx(e0)
    fac.weights = np.zeros((1, 8))
    assert g2.error(v) == 0.0


def test_gradient_image_samples_next_to_clipped_pixels_are_invalid():
    rng = np.random.default_rng(3)
    img = rng.uniform(20, 200, (30, 40))
    img[10, 20] = 255.0  # saturated
    img[20, 5] = 0.0  # black-clipped
    g, plain = GradientImage(img), GradientImage(img, clip_range=None)
    assert g.clip_range == (0.0, 255.0) and plain.clip_range is None
    # every sample whose bilinear cell holds a clipped pixel, and a few that do not
    u = np.array([19.5, 20.0, 20.9, 19.01, 4.5, 5.5, 21.2, 18.9, 6.1, 30.0])
    v = np.array([9.5, 10.0, 10.9, 9.01, 19.5, 20.5, 10.0, 10.0, 20.0, 25.0])
    a, va = g.sample(u, v)
    b, vb = plain.sample(u, v)
    np.testing.assert_array_equal(va, [False] * 6 + [True] * 4)
    assert vb.all()
    np.testing.assert_array_equal(a[va], b[va])
    assert np.all(a[~va] == 0)
    # an image without clipped pixels skips the check; the kernel counts clipped samples as outside
    assert g.has_clipped and not plain.has_clipped and not GradientImage(rng.uniform(1, 254, (8, 8))).has_clipped
    cam = small_camera()
    px = np.array([[20.0, 10.0], [30.0, 25.0]])
    Ih, hv = sample_host(plain, px)
    L = photometric_residuals(cam, Ih, hv, px, [0.5, 0.5], gtsam.Pose3(), gtsam.Pose3(), g)
    assert not L.valid[0, 4] and L.valid[1].all() and L.n_outside == np.count_nonzero(~L.valid)
    with pytest.raises(InputError):
        GradientImage(img, clip_range="auto")
