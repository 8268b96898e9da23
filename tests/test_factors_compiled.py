"""The compiled loops (factors/_compiled.py) against the numpy forms they replace.

``photometric_residuals`` takes the compiled path for a :class:`GradientImage` target and the
numpy path for any other sampler; wrapping the same image in a plain sampler object runs the
numpy path on identical samples, so every output must agree to rounding. The numpy path's
Jacobians are checked against numerical derivatives in test_factors_jacobians.py; here the
compiled path's are checked against them too, on a smooth raster. ``gauss_newton_sums`` (the
window's Hessian accumulation) is checked against the numpy sums it replaced, in both its forms.
"""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from factors import _compiled_sums
from factors.host_points import gauss_newton_sums, target_jacobian_map, target_jacobian_maps, target_normal_equations
from factors.photometric import (GradientImage, PhotometricLinearization, compiled_residuals, pattern_bearings,
                                 photometric_residuals, put_rows, sample_host, stereo_residuals)
from factors.weights import huber_loss, huber_weight, point_robust_terms
from gtvo.errors import InputError
from tests._factors_synthetic import SinusoidImage, small_camera

FIELDS = ("residual", "valid", "J_depth", "J_host", "J_target", "J_affine_host", "J_affine_target", "uv_target")


class NumpySampler:
    """The same image behind the plain sampler protocol: photometric_residuals' numpy path."""

    def __init__(self, image: GradientImage) -> None:
        self.image, self.width, self.height = image, image.width, image.height

    def sample(self, u, v):
        return self.image.sample(u, v)


def assert_same(a: PhotometricLinearization, b: PhotometricLinearization) -> None:
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is None:
            continue
        x, y = np.asarray(x, float), np.asarray(y, float)
        assert x.shape == y.shape, name
        scale = max(np.abs(y).max(), 1.0)
        assert np.abs(x - y).max() <= 1e-12 * scale, f"{name}: {np.abs(x - y).max():.3g}"
    assert (a.n_bad_depth, a.n_behind, a.n_outside) == (b.n_bad_depth, b.n_behind, b.n_outside)


def textured(rng, h=120, w=160):
    img = rng.normal(128, 70, (h, w))
    img = np.clip(img + np.roll(img, 1, 0) + np.roll(img, 1, 1), 0, 3 * 255) / 3  # some spatial correlation
    img[:25, :40] = 255.0  # a saturated patch: clipped cells are invalid
    img[90:, 130:] = 0.0  # and a black-clipped one
    return img


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("jacobians,host_jacobians", [(True, True), (True, False), (False, False)])
def test_compiled_path_equals_numpy_path(seed, jacobians, host_jacobians):
    rng = np.random.default_rng(seed)
    cam = small_camera()
    host, target = GradientImage(textured(rng)), GradientImage(textured(rng))
    n = 200
    px = np.c_[rng.uniform(3, 157, n), rng.uniform(3, 117, n)]
    d = rng.uniform(0.05, 2.0, n)
    d[:4] = [-0.5, 0.0, np.nan, np.inf]  # bad inverse depths
    d[4:8] = 40.0  # points 2.5 cm in front of the host: behind a target 0.3 m ahead
    Th = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.05, 3)), rng.normal(0, 0.2, 3))
    Tt = Th.compose(gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.05, 3)), np.array([0.05, -0.02, 0.3])))
    Ih, hv = sample_host(host, px)
    args = (cam, Ih, hv, px, d, Th, Tt)
    kw = dict(affine_host=rng.normal(0, 0.2, 2), affine_target=rng.normal(0, 0.2, 2), jacobians=jacobians,
              host_jacobians=host_jacobians)
    a = photometric_residuals(*args, target, **kw)
    b = photometric_residuals(*args, NumpySampler(target), **kw)
    assert_same(a, b)
    # every kind of invalid residual occurs, and most are valid
    assert a.n_bad_depth == 4 and a.n_behind > 0 and a.n_outside > 0 and 0.4 < a.valid.mean() < 0.95
    assert not hv.all()  # the host's clipped patch too
    # precomputed bearings give the same result
    assert_same(photometric_residuals(*args, target, bearings=pattern_bearings(cam, px), **kw), a)


def test_compiled_stereo_residuals_equal_numpy_path():
    rng = np.random.default_rng(7)
    cam = small_camera()
    left, right = GradientImage(textured(rng)), GradientImage(textured(rng))
    px = np.c_[rng.uniform(3, 157, 100), rng.uniform(3, 117, 100)]
    d = rng.uniform(0.1, 1.0, 100)
    Il, lv = sample_host(left, px)
    a = stereo_residuals(cam, 0.3, Il, lv, px, d, right, (0.1, 2.0), (-0.1, 1.0))
    b = stereo_residuals(cam, 0.3, Il, lv, px, d, NumpySampler(right), (0.1, 2.0), (-0.1, 1.0))
    assert_same(a, b)


def test_compiled_path_jacobians_against_numerical_derivatives():
    """The derivative of a bilinear interpolant is a one-sided difference between pixels, while
    the kernel interpolates central differences (DSO's choice too): on a raster the two differ
    in proportion to the texture's frequency (measured 5 % at a wavelength of 40 px, 2 % at
    100 px, used here). The affine Jacobians do not sample gradients and agree to rounding; the
    exact chain rule is test_compiled_path_equals_numpy_path + test_factors_jacobians.py."""
    rng = np.random.default_rng(3)
    cam = small_camera()
    smooth = SinusoidImage(seed=5, wavelength=100.0, n_waves=3)
    host, target = GradientImage(smooth.raster()), GradientImage(smooth.raster())
    n = 40
    px = np.c_[rng.uniform(30, 130, n), rng.uniform(30, 90, n)]
    d = rng.uniform(0.3, 1.0, n)
    Th = gtsam.Pose3()
    Tt = gtsam.Pose3(gtsam.Rot3.Expmap([0.01, -0.02, 0.01]), np.array([0.05, 0.02, 0.1]))
    ah, at = np.array([0.1, 3.0]), np.array([-0.1, 1.0])
    Ih, hv = sample_host(host, px)
    L = photometric_residuals(cam, Ih, hv, px, d, Th, Tt, target, ah, at)
    assert L.valid.all()

    def res(Th_=Th, Tt_=Tt, d_=d, at_=at):
        out = photometric_residuals(cam, Ih, hv, px, d_, Th_, Tt_, target, ah, at_, jacobians=False)
        assert out.valid.all()
        return out.residual

    h = 1e-5
    numeric_target = np.stack([(res(Tt_=Tt.retract(h * e)) - res(Tt_=Tt.retract(-h * e))) / (2 * h)
                               for e in np.eye(6)], -1)
    numeric_host = np.stack([(res(Th_=Th.retract(h * e)) - res(Th_=Th.retract(-h * e))) / (2 * h)
                             for e in np.eye(6)], -1)
    numeric_depth = (res(d_=d + h) - res(d_=d - h)) / (2 * h)
    numeric_aff = np.stack([(res(at_=at + h * e) - res(at_=at - h * e)) / (2 * h) for e in np.eye(2)], -1)
    for analytic, numeric in ((L.J_target, numeric_target), (L.J_host, numeric_host), (L.J_depth, numeric_depth)):
        err = np.abs(analytic - numeric).max() / np.abs(numeric).max()
        assert err < 0.03, err
    np.testing.assert_allclose(L.J_affine_target, numeric_aff, rtol=1e-7, atol=1e-7)


def test_sample_keeps_the_shape_and_rejects_mismatched_coordinates():
    g = GradientImage(np.random.default_rng(0).uniform(1, 254, (20, 30)))
    vals, ok = g.sample(np.full((2, 3, 4), 5.5), np.full((2, 3, 4), 7.25))
    assert vals.shape == (2, 3, 4, 3) and ok.shape == (2, 3, 4) and ok.all()
    vals, ok = g.sample(5.5, 7.25)  # scalars
    assert vals.shape == (3,) and ok.shape == () and bool(ok)
    with pytest.raises(Exception, match="shape"):
        g.sample(np.zeros(3), np.zeros(4))


HOST_POSE = gtsam.Pose3(gtsam.Rot3.Expmap([0.3, -0.2, 0.1]), np.array([1.0, -0.5, 2.0]))


def _host_and_target(rng: np.random.Generator, n: int, rotation: list, translation: list) -> tuple:
    """Two textured images, ``n`` random host pixels with inverse depths in [0.1, 1.5], the target's
    pose (``HOST_POSE`` moved by the rotation vector and translation) and the host samples:
    ``(host, target, px, d, T_world_target, I_host, host_valid)``."""
    host, target = GradientImage(textured(rng)), GradientImage(textured(rng))
    px = np.c_[rng.uniform(3, 157, n), rng.uniform(3, 117, n)]
    d = rng.uniform(0.1, 1.5, n)
    Tt = HOST_POSE.compose(gtsam.Pose3(gtsam.Rot3.Expmap(rotation), np.array(translation)))
    Ih, hv = sample_host(host, px)
    return host, target, px, d, Tt, Ih, hv



@pytest.mark.parametrize("sums", ["pair", "general"])
@pytest.mark.parametrize("with_affine", [True, False])
def test_gauss_newton_sums_equal_the_numpy_sums(with_affine, sums):
    """``pair``: the kernels' linearisation carries ``T_target_host`` and the gain, so the sums are
    mapped from the host Jacobians (accumulate_pair); ``general``: without them (accumulate_target)."""
    rng = np.random.default_rng(11)
    cam = small_camera()
    host, target, px, d, Tt, Ih, hv = _host_and_target(rng, 150, [0.01, 0.02, -0.01], [0.1, 0.0, 0.2])
    lin = photometric_residuals(cam, Ih, hv, px, d, HOST_POSE, Tt, target, (0.1, 1.0), (-0.2, 3.0))
    assert lin.T_target_host is not None and lin.brightness_gain is not None
    if sums == "general":
        lin = dataclasses.replace(lin, T_target_host=None, brightness_gain=None)
    weight = rng.uniform(0.0, 2.0, lin.residual.shape)  # not zero where invalid: as the window's W
    assert not lin.valid.all()
    weight[:10] = 0.0
    H, g, H_pd, H_dd, g_d = gauss_newton_sums(lin, weight, with_affine)
    parts = [lin.J_host, lin.J_affine_host, lin.J_target, lin.J_affine_target] if with_affine \
        else [lin.J_host, lin.J_target]
    J = np.concatenate(parts, axis=-1)
    k = J.shape[-1]
    assert H.shape == (k, k) and H_pd.shape == (150, k)
    Jw = J * weight[..., None]
    np.testing.assert_allclose(H, Jw.reshape(-1, k).T @ J.reshape(-1, k), rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(g, Jw.reshape(-1, k).T @ lin.residual.reshape(-1), rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(H_pd, np.einsum("npk,np->nk", Jw, lin.J_depth), rtol=1e-10, atol=1e-6)
    np.testing.assert_allclose(H_dd, np.sum(weight * lin.J_depth ** 2, axis=1), rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(g_d, np.sum(weight * lin.J_depth * lin.residual, axis=1), rtol=1e-10, atol=1e-9)
    assert np.all(H_pd[:10] == 0) and np.all(H_dd[:10] == 0)
    assert np.linalg.eigvalsh(H).min() > -1e-6 * np.abs(H).max()


def test_put_rows_keeps_the_pair_pose_only_when_both_share_it():
    """Rows evaluated at another pair pose: the merged linearisation loses ``T_target_host`` (its
    sums then need ``J_target``), at the same pose it keeps it."""
    rng = np.random.default_rng(9)
    cam = small_camera()
    host, target = GradientImage(textured(rng)), GradientImage(textured(rng))
    px = np.c_[rng.uniform(3, 157, 30), rng.uniform(3, 117, 30)]
    Ih, hv = sample_host(host, px)
    Tt = gtsam.Pose3(gtsam.Rot3(), np.array([0.1, 0.0, 0.0]))
    a = photometric_residuals(cam, Ih, hv, px, np.full(30, 0.5), gtsam.Pose3(), Tt, target)
    same = photometric_residuals(cam, Ih, hv, px, np.full(30, 0.6), gtsam.Pose3(), Tt, target)
    other = photometric_residuals(cam, Ih, hv, px, np.full(30, 0.6), gtsam.Pose3(), Tt.compose(Tt), target)
    rows = np.array([1, 4, 7])
    merged = put_rows(dataclasses.replace(a), rows, same, rows)
    assert merged.T_target_host is not None and merged.brightness_gain is not None
    np.testing.assert_array_equal(merged.residual[rows], same.residual[rows])
    mixed = put_rows(dataclasses.replace(a), rows, other, rows)
    assert mixed.T_target_host is None and mixed.brightness_gain is None


@pytest.mark.parametrize("with_affine", [True, False])
def test_target_normal_equations_equal_the_numpy_sums(with_affine):
    """The tracker's normal equations (frame pose and affine only) against the numpy products."""
    rng = np.random.default_rng(12)
    cam = small_camera()
    host, target = GradientImage(textured(rng)), GradientImage(textured(rng))
    px = np.c_[rng.uniform(3, 157, 120), rng.uniform(3, 117, 120)]
    d = rng.uniform(0.1, 1.5, 120)
    Tt = gtsam.Pose3(gtsam.Rot3.Expmap([0.01, 0.02, -0.01]), np.array([0.1, 0.0, 0.2]))
    Ih, hv = sample_host(host, px)
    lin = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), Tt, target, (0.1, 1.0), (-0.2, 3.0),
                                host_jacobians=False)
    assert not lin.valid.all()
    weight = rng.uniform(0.0, 2.0, lin.residual.shape)
    A, b = target_normal_equations(lin, weight, with_affine)
    J = np.concatenate([lin.J_target, lin.J_affine_target], axis=-1) if with_affine else lin.J_target
    k = J.shape[-1]
    J = J.reshape(-1, k)
    Jw = J * weight.reshape(-1, 1)
    assert A.shape == (k, k) and b.shape == (k,)
    np.testing.assert_allclose(A, J.T @ Jw, rtol=1e-12, atol=1e-9 * np.abs(A).max())
    np.testing.assert_allclose(b, Jw.T @ lin.residual.reshape(-1), rtol=1e-12, atol=1e-9 * np.abs(b).max())
    with pytest.raises(InputError, match="target Jacobians"):
        target_normal_equations(dataclasses.replace(lin, J_target=None), weight)
    with pytest.raises(InputError, match="shape"):
        target_normal_equations(lin, weight[:, :4])


@pytest.mark.parametrize("compiled", [True, False])
def test_target_jacobians_are_the_host_jacobians_mapped_by_the_pair(compiled):
    """The fact accumulate_pair rests on: ``J_target = J_host B^T``, ``B`` of ``T_target_host``
    alone, for both kernels, with both poses away from the identity; and the affine Jacobians
    are ``(hb, gain)`` and ``(-hb, -1)``."""
    rng = np.random.default_rng(5)
    cam = small_camera()
    host, target, px, d, Tt, Ih, hv = _host_and_target(rng, 100, [-0.02, 0.03, 0.01], [0.2, 0.1, -0.1])
    sampler = target if compiled else NumpySampler(target)
    lin = photometric_residuals(cam, Ih, hv, px, d, HOST_POSE, Tt, sampler, (0.1, 1.0), (-0.2, 3.0))
    assert lin.valid.sum() > 300
    np.testing.assert_allclose(lin.T_target_host, Tt.between(HOST_POSE).matrix(), atol=1e-12)
    B = target_jacobian_map(lin.T_target_host)
    scale = np.abs(lin.J_target).max()
    np.testing.assert_allclose(lin.J_host @ B.T, lin.J_target, rtol=0, atol=1e-12 * scale)
    assert lin.brightness_gain == pytest.approx(np.exp(-0.3))
    np.testing.assert_allclose(lin.J_affine_target[..., 0], -lin.J_affine_host[..., 0], atol=0)
    np.testing.assert_allclose(lin.J_affine_host[..., 1], lin.brightness_gain * lin.valid, rtol=1e-15)
    np.testing.assert_allclose(lin.J_affine_target[..., 1], -1.0 * lin.valid, atol=0)


@pytest.mark.slow
def test_compiled_residuals_without_target_jacobians_and_their_sums():
    """``target_jacobians=False`` (the window's passes): the target blocks are left out, the rest is
    the same to the bit, and the Gauss-Newton sums (mapped from the host Jacobians) are the same."""
    rng = np.random.default_rng(8)
    cam = small_camera()
    host, target, px, d, Tt, Ih, hv = _host_and_target(rng, 80, [0.01, -0.02, 0.01], [0.1, 0.05, 0.1])
    f = pattern_bearings(cam, px)
    args = (cam, Ih, hv, f, d, HOST_POSE, Tt, target, 0.2, 1.0, 3.0)
    full = compiled_residuals(*args)
    lean = compiled_residuals(*args, target_jacobians=False)
    assert lean.J_target is None and lean.J_affine_target is None
    for name in ("residual", "valid", "J_depth", "J_host", "J_affine_host", "uv_target"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(full, name))
    weight = rng.uniform(0.5, 2.0, full.residual.shape)
    general = dataclasses.replace(full, T_target_host=None, brightness_gain=None)  # sums of J_target itself
    for a, b in zip(gauss_newton_sums(lean, weight), gauss_newton_sums(general, weight)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * max(np.abs(b).max(), 1e-300))
    with pytest.raises(InputError, match="Jacobians"):
        gauss_newton_sums(dataclasses.replace(lean, T_target_host=None), weight)


@pytest.mark.parametrize("k", [None, 0.5, 3.0, 1e9])
def test_point_robust_terms_equal_the_numpy_huber(k):
    rng = np.random.default_rng(3)
    W = rng.uniform(0.0, 2.0, (200, 8))
    r = rng.normal(0.0, 2.0, (200, 8))
    r[:5] = 0.0  # zero norm: weight 1, loss 0
    w, loss = point_robust_terms(W, r, k)
    x = np.sqrt(np.sum(W * r * r, axis=1))
    if k is None:
        np.testing.assert_array_equal(w, 1.0)
        np.testing.assert_allclose(loss, 0.5 * x * x, rtol=1e-14, atol=0)
    else:
        np.testing.assert_allclose(w, huber_weight(x, k), rtol=1e-14, atol=0)
        np.testing.assert_allclose(loss, huber_loss(x, k), rtol=1e-14, atol=0)
        assert k > 1e8 or np.any(w < 1.0)  # both branches of the kernel are exercised
    with pytest.raises(InputError, match="point_robust_terms"):
        point_robust_terms(W[:, :4], r, k)


def test_gauss_newton_sums_reject_missing_jacobians_and_bad_weights():
    rng = np.random.default_rng(1)
    cam = small_camera()
    img = GradientImage(textured(rng))
    px = np.array([[50.0, 50.0], [70.0, 60.0]])
    Ih, hv = sample_host(img, px)
    lin = photometric_residuals(cam, Ih, hv, px, [0.5, 0.5], gtsam.Pose3(), gtsam.Pose3(), img, jacobians=False)
    with pytest.raises(InputError, match="Jacobians"):
        gauss_newton_sums(lin, np.ones((2, 8)))
    lin = photometric_residuals(cam, Ih, hv, px, [0.5, 0.5], gtsam.Pose3(), gtsam.Pose3(), img)
    with pytest.raises(InputError, match="shape"):
        gauss_newton_sums(lin, np.ones((2, 7)))


def test_jit_compiles_without_a_cache_location():
    """numba cannot cache a function whose source is not a file (as with a read-only install and
    no home directory); ``jit`` then compiles without a cache instead of raising at import."""
    from gtvo.core.jit import jit
    namespace: dict = {}
    exec(compile("def twice(x):\n    return 2.0 * x\n", "<no file>", "exec"), namespace)
    fn = jit(namespace["twice"])
    assert fn(1.5) == 3.0


def _packed_numpy(img, clip_range):
    """GradientImage's record array as numpy made it (the reference of pack_gradient_image)."""
    from gtvo.core.image import image_gradients  # noqa: PLC0415

    gx, gy = image_gradients(img)
    packed = np.zeros(img.shape + (4,), dtype=np.float32)
    packed[..., 0], packed[..., 1], packed[..., 2] = img, gx, gy
    clipped_any = False
    if clip_range is not None:
        clipped = (img <= clip_range[0]) | (img >= clip_range[1])
        if clipped.any():
            packed[:-1, :-1, 3] = clipped[:-1, :-1] | clipped[1:, :-1] | clipped[:-1, 1:] | clipped[1:, 1:]
            clipped_any = True
    return packed, clipped_any


@pytest.mark.parametrize("clip_range", [None, (0.0, 255.0), (0.5, 254.7), (30.0, 200.0)])
@pytest.mark.parametrize("shape,whole", [((2, 2), True), ((3, 7), True), ((48, 64), True), ((2, 9), False),
                                         ((37, 53), False)])
def test_gradient_image_records_equal_the_numpy_form(clip_range, shape, whole):
    """GradientImage packs intensity, gradients and the clipped-cell flag in one compiled pass: the
    records of the numpy form, bit for bit (clip limits compared in float32 as numpy does), for
    whole grey levels and for fractional ones (the halved central differences' rounding)."""
    from factors.photometric import GradientImage  # noqa: PLC0415

    rng = np.random.default_rng(shape[1])
    img = rng.random(shape) * 260.0 - 2.0
    img = (np.round(img) if whole else img).astype(np.float32)
    img[0, 0] = 254.7  # on the float32 edge of a clip limit
    g = GradientImage(img, clip_range=clip_range)
    ref, clipped = _packed_numpy(img, clip_range)
    assert np.array_equal(g._packed.reshape(ref.shape), ref)
    assert g.has_clipped == clipped
    bad = img.copy()
    bad[-1, -1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        GradientImage(bad, clip_range=clip_range)


def test_target_jacobian_map_is_the_inverse_adjoint_to_the_bit():
    """The written-out map equals ``-se3_adjoint(R^T, -R^T t)^T`` byte for byte (the window's numbers
    did not move when it replaced the stacked form)."""
    import gtsam  # noqa: PLC0415

    from gtvo.core.lie import se3_adjoint  # noqa: PLC0415

    rng = np.random.default_rng(3)
    for _ in range(300):
        T = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 1, 3)), rng.normal(0, 5, 3)).matrix()
        R, t = T[:3, :3], T[:3, 3]
        assert target_jacobian_map(T).tobytes() == (-se3_adjoint(R.T, -R.T @ t).T).tobytes()


def test_target_jacobian_maps_equal_one_at_a_time_to_the_bit():
    """The batched maps (a host's pairs in one call) are the single maps byte for byte."""
    rng = np.random.default_rng(4)
    T = np.stack([gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 1, 3)), rng.normal(0, 5, 3)).matrix() for _ in range(64)])
    B = target_jacobian_maps(T)
    assert B.shape == (64, 6, 6)
    assert B.tobytes() == np.stack([target_jacobian_map(t) for t in T]).tobytes()


@pytest.mark.parametrize("p", [1, 7, 8, 9, 20, 128])
@pytest.mark.parametrize("k", [None, 0.8])
def test_depth_terms_equal_the_numpy_expressions_to_the_bit(p, k):
    """The compiled stereo and prior terms on the depths are the numpy expressions they replaced
    (row sums by numpy's pairwise summation), byte for byte, with and without each term."""
    rng = np.random.default_rng(p)
    n = 50
    W = rng.uniform(0.01, 2, (n, p))
    r = rng.normal(0, 3, (n, p)) * 10 ** rng.uniform(-3, 3, (n, p))
    j = rng.normal(0, 50, (n, p))
    d, prior, V = rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n), rng.uniform(1e-4, 1e-1, n)
    start = [rng.normal(size=n) for _ in range(3)]
    for stereo in (False, True):
        for prior_on in (False, True):
            want = [a.copy() for a in start]
            w_want = np.ones(n)
            if stereo:
                w_want, loss = point_robust_terms(W, r, k)
                ww = W * w_want[:, None]
                want[0] += np.sum(ww * j ** 2, axis=1)
                want[1] += np.sum(ww * j * r, axis=1)
                want[2] += loss
            if prior_on:
                want[0] += 1.0 / V
                want[1] += (d - prior) / V
                want[2] += 0.5 * (d - prior) ** 2 / V
            got = [a.copy() for a in start]
            w = _compiled_sums.add_depth_terms(W, r, j, 0.0 if k is None else k, k is not None, stereo, d, prior, V,
                                               prior_on, *got)
            assert w.tobytes() == w_want.tobytes()
            for a, b in zip(got, want):
                assert a.tobytes() == b.tobytes()


def test_pair_sums_skip_the_invalid_residuals_to_the_bit():
    """The pair sums skip the residuals flagged invalid (their residual and Jacobians are zero): the
    same sums, byte for byte, as summing every residual; the points outside the target are many."""
    rng = np.random.default_rng(11)
    cam = small_camera()
    host, target, px, d, Tt, Ih, hv = _host_and_target(rng, 120, [0.01, -0.02, 0.01], [0.4, 0.05, 0.1])
    lin = compiled_residuals(cam, Ih, hv, pattern_bearings(cam, px), d, HOST_POSE, Tt, target, 0.2, 1.0, 3.0,
                             target_jacobians=False)
    assert 0.1 < (~lin.valid).mean() < 0.9
    weight = rng.uniform(0.5, 2.0, lin.residual.shape)  # invalid residuals weighed too
    B = target_jacobian_map(lin.T_target_host)
    args = (lin.J_host, lin.J_affine_host, B, float(lin.brightness_gain), weight, lin.residual, lin.J_depth)
    skipped = _compiled_sums.accumulate_pair(*args, lin.valid)
    every = _compiled_sums.accumulate_pair(*args, np.zeros((0, 1), dtype=bool))
    for a, b in zip(skipped, every):
        assert a.tobytes() == b.tobytes()


def _scalar_gram8(J6, J2, weight, residual, J_depth, valid):
    """:func:`factors._compiled_sums._gram8`'s sums one scalar at a time (Python floats, IEEE doubles),
    in the order and with the products of ``gram8_add``: the reference its vector lanes must match."""
    n, p = residual.shape
    H, g = np.zeros((8, 8)), np.zeros(8)
    HpdK, H_dd, g_d = np.zeros((n, 8)), np.zeros(n), np.zeros(n)
    for i in range(n):
        q, hd, gd = [0.0] * 8, 0.0, 0.0
        for m in range(p):
            if not valid[i, m]:
                continue
            w, r, jd = float(weight[i, m]), float(residual[i, m]), float(J_depth[i, m])
            K = [float(x) for x in J6[i, m]] + ([float(x) for x in J2[i, m]] if J2.shape[0] else [0.0, 0.0])
            for a in range(8):
                wa = w * K[a]
                g[a] += wa * r
                q[a] += wa * jd
                for b in range(a, 8):
                    H[a, b] += wa * K[b]
            hd += w * jd * jd
            gd += w * jd * r
        HpdK[i], H_dd[i], g_d[i] = q, hd, gd
    return H + np.triu(H, 1).T, g, HpdK, H_dd, g_d


@pytest.mark.parametrize("with_affine", [True, False])
@pytest.mark.parametrize("per_point", [True, False])
@pytest.mark.parametrize("contiguous", [True, False])
def test_vector_sums_equal_the_scalar_sums_to_the_bit(with_affine, per_point, contiguous):
    """The Gauss-Newton sums add each residual eight lanes at a time: the same values, byte for byte,
    as the scalar sums (each a multiplication then an addition, residual after residual), with
    invalid residuals skipped, with and without affine columns, from strided Jacobians too."""
    rng = np.random.default_rng(5)
    n, p = 23, 8
    big = rng.normal(size=(n, p, 9)) * 10.0 ** rng.integers(-3, 3, size=(n, p, 1))
    J6 = big[..., :6] if not contiguous else np.ascontiguousarray(big[..., :6])
    J2 = (big[..., 6:8] if not contiguous else np.ascontiguousarray(big[..., 6:8])) if with_affine else np.zeros((0, 1, 2))
    weight, residual, J_depth = rng.uniform(0.1, 3.0, (n, p)), rng.normal(size=(n, p)), rng.normal(size=(n, p))
    valid = rng.uniform(size=(n, p)) > 0.3
    got = _compiled_sums._gram8(J6, J2, weight, residual, J_depth, per_point, valid)
    want = _scalar_gram8(J6, J2, weight, residual, J_depth, valid)
    if not per_point:
        want = want[:2] + (np.zeros((0, 8)), np.zeros(0), np.zeros(0))
    for a, b in zip(got, want):
        assert a.shape == b.shape and a.tobytes() == b.tobytes()
