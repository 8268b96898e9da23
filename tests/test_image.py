import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.core.image import (as_float_gray, bilinear_sample, build_pyramid, downsample, image_gradients,
                             to_float_gray)


def ramp(h=6, w=8):
    v, u = np.mgrid[0:h, 0:w]
    return (3.0 * u + 10.0 * v).astype(np.float32)


def test_bilinear_exact_on_affine_image():
    img = ramp()
    u = np.array([0.0, 1.25, 6.5, 7.0])
    v = np.array([0.0, 2.5, 4.75, 5.0])
    val, ok = bilinear_sample(img, u, v)
    assert ok.all()
    np.testing.assert_allclose(val, 3 * u + 10 * v)


def test_bilinear_hand_computed_corner():
    img = np.array([[0.0, 10.0], [20.0, 40.0]], dtype=np.float32)
    val, ok = bilinear_sample(img, np.array([0.5]), np.array([0.5]))
    assert ok[0] and val[0] == pytest.approx(17.5)


def test_bilinear_border_and_nan_masked():
    img = ramp()
    u = np.array([-0.01, 7.01, 3.0, np.nan, 0.5])
    v = np.array([1.0, 1.0, 5.2, 1.0, 0.5])
    val, ok = bilinear_sample(img, u, v)
    np.testing.assert_array_equal(ok, [False, False, False, False, True])
    assert np.all(np.isfinite(val)) and np.all(val[~ok] == 0)
    _, ok2 = bilinear_sample(img, np.array([0.5]), np.array([0.5]), border=1.0)
    assert not ok2[0]


def test_bilinear_multichannel():
    img = ramp()
    stack = np.dstack([img, 2 * img])
    val, ok = bilinear_sample(stack, np.array([2.5]), np.array([1.5]))
    np.testing.assert_allclose(val[0], [3 * 2.5 + 15, 2 * (3 * 2.5 + 15)])


def test_gradients_of_ramp():
    gx, gy = image_gradients(ramp())
    np.testing.assert_allclose(gx, 3.0)
    np.testing.assert_allclose(gy, 10.0)


def test_pyramid_block_average():
    img = ramp(8, 8)
    d = downsample(img)
    assert d.shape == (4, 4)
    assert d[0, 0] == pytest.approx(np.mean(img[:2, :2]))
    pyr = build_pyramid(np.zeros((64, 100)), levels=5, min_size=8)
    assert [p.shape for p in pyr] == [(64, 100), (32, 50), (16, 25), (8, 12)]


def test_to_float_gray():
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[..., 2] = 100  # red
    g = to_float_gray(bgr)
    assert g.dtype == np.float32 and g[0, 0] == pytest.approx(29.9, rel=1e-5)
    with pytest.raises(InputError):
        to_float_gray(np.zeros((2, 2, 2, 2)))
    with pytest.raises(InputError, match="NaN"):
        to_float_gray(np.full((2, 2), np.nan))


def test_to_float_gray_scales_16_bit_to_8_bit_units():
    g8 = np.array([[0, 1, 128, 255]], np.uint8)
    g16 = g8.astype(np.uint16) * 257  # the same intensities logged with 16 bits
    np.testing.assert_allclose(to_float_gray(g16), to_float_gray(g8), rtol=1e-6)
    bgr16 = np.zeros((1, 1, 3), np.uint16)
    bgr16[..., 2] = 100 * 257
    assert to_float_gray(bgr16)[0, 0] == pytest.approx(29.9, rel=1e-5)


def _bilinear_numpy(img, u, v, border=0.0):
    """bilinear_sample's vectorised numpy form (the reference of its compiled loop)."""
    h, w = img.shape[:2]
    valid = np.isfinite(u) & np.isfinite(v) & (u >= border) & (u <= w - 1 - border) & (v >= border) & (v <= h - 1 - border)
    us, vs = np.where(valid, u, 0.0), np.where(valid, v, 0.0)
    x0 = np.maximum(np.minimum(np.floor(us).astype(np.intp), w - 2), 0)
    y0 = np.maximum(np.minimum(np.floor(vs).astype(np.intp), h - 2), 0)
    ax, ay = us - x0, vs - y0
    flat = img.reshape(h * w, *img.shape[2:])
    i00 = y0 * w + x0
    if img.ndim == 3:
        ax, ay = ax[..., None], ay[..., None]
    out = (1 - ay) * ((1 - ax) * flat[i00] + ax * flat[i00 + 1]) + ay * ((1 - ax) * flat[i00 + w] + ax * flat[i00 + w + 1])
    return np.where(valid[..., None] if img.ndim == 3 else valid, out, 0.0), valid


@pytest.mark.parametrize("channels", [None, 1, 3])
@pytest.mark.parametrize("border", [0.0, 2.5])
def test_compiled_bilinear_sampling_equals_the_numpy_form(channels, border):
    """float32 images take one compiled loop: the same values and mask as the numpy form, bit for
    bit, NaN and out-of-image positions included."""
    rng = np.random.default_rng(7)
    shape = (40, 60) if channels is None else (40, 60, channels)
    img = (rng.random(shape) * 255).astype(np.float32)
    u, v = rng.uniform(-3, 63, (30, 7)), rng.uniform(-3, 43, (30, 7))
    u[0, 0], v[1, 1] = np.nan, np.inf
    vals, ok = bilinear_sample(img, u, v, border)
    ref, ref_ok = _bilinear_numpy(img, u, v, border)
    assert vals.shape == ref.shape and vals.dtype == np.float64
    assert np.array_equal(vals, ref) and np.array_equal(ok, ref_ok)


def _downsample_numpy(img):
    """downsample's numpy form (the reference of its compiled loop)."""
    img = np.asarray(img, dtype=np.float32)
    h, w = (img.shape[0] // 2) * 2, (img.shape[1] // 2) * 2
    img = img[:h, :w]
    return 0.25 * (img[0::2, 0::2] + img[1::2, 0::2] + img[0::2, 1::2] + img[1::2, 1::2])


@pytest.mark.parametrize("shape", [(1, 1), (2, 2), (3, 7), (97, 131), (370, 1226)])
def test_compiled_downsample_equals_the_numpy_form(shape):
    """Bit for bit, on values whose float32 sums depend on their order (odd sizes drop a row / column)."""
    rng = np.random.default_rng(sum(shape))
    for img in (rng.random(shape) * 255, rng.exponential(1.0, shape) * 10.0 ** rng.integers(-8, 8, shape),
                rng.integers(0, 256, shape).astype(np.uint8)):
        got = downsample(img)
        ref = _downsample_numpy(img)
        assert got.dtype == ref.dtype == np.float32 and got.shape == ref.shape
        assert np.array_equal(got, ref)


def test_as_float_gray_keeps_float_gray_and_converts_the_rest():
    img = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert as_float_gray(img) is img  # converted already: not copied, not scanned again
    u8 = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert as_float_gray(u8).dtype == np.float32 and np.array_equal(as_float_gray(u8), img)
    with pytest.raises(InputError, match="right image contains NaN"):
        as_float_gray(np.full((2, 2), np.nan), "right image")  # float64: converted, so checked


def _count_conversions(monkeypatch) -> dict[str, int]:
    """Count ``to_float_gray`` calls by image (``left``/``right``/other) in every gtvo module that
    imported it (``from gtvo.core.image import to_float_gray`` binds the name in each)."""
    import sys  # noqa: PLC0415

    import gtvo.core.image as image  # noqa: PLC0415

    original, counts = image.to_float_gray, {"left": 0, "right": 0, "other": 0}

    def counting(img, name="image"):
        side = next((s for s in ("left", "right") if s in name), "other")
        counts[side] += 1
        return original(img, name)

    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("gtvo") and getattr(module, "to_float_gray", None) is original:
            monkeypatch.setattr(module, "to_float_gray", counting)
    return counts


@pytest.mark.slow
@pytest.mark.parametrize("window", [False, True])
def test_a_run_converts_each_image_to_float_once(tmp_path, monkeypatch, window):
    """Over a short run of a KITTI-layout folder (every frame a keyframe at this motion), each left
    and right image passes ``to_float_gray`` once: where the reader loads it, never again."""
    import gtvo  # noqa: PLC0415
    from gtvo.datasets.synthetic import make_synthetic_sequence, write_sequence_kitti  # noqa: PLC0415
    import gtvo.pipeline  # noqa: F401, PLC0415 - every module of a run imported, so that all are counted

    folder = write_sequence_kitti(make_synthetic_sequence(n_frames=6), tmp_path / "seq")
    counts = _count_conversions(monkeypatch)
    config = {"mode": "window" if window else "track", "window": {"covariances": False},
              "keyframes": {"max_motion": 0.0, "max_flow": 0.0}}  # every frame a keyframe
    report = gtvo.run(folder, out=tmp_path / "out", config=config)
    assert report["frames"] == 6 and report["keyframes"] >= 3
    assert counts == {"left": 6, "right": 6, "other": 0}
