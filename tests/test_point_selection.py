import numpy as np
import pytest

from gtvo.errors import InputError
from gtvo.frontend import DEFAULT_BORDER, block_gradient_thresholds, gradient_magnitude, select_points

from _synthetic_stereo import texture


def textured(h=240, w=320, seed=0):
    v, u = np.mgrid[0:h, 0:w].astype(float)
    return texture(u, v, seed).astype(np.float32)


def test_count_near_target_and_spread_over_quadrants():
    img = textured()
    for target in (300, 1000):
        px = select_points(img, target=target)
        assert 0.9 * target <= len(px) <= target
        h, w = img.shape
        for top in (True, False):
            for lefth in (True, False):
                q = ((px[:, 1] < h / 2) == top) & ((px[:, 0] < w / 2) == lefth)
                # uniform texture: each quadrant holds about a quarter of the points
                assert 0.15 * len(px) < q.sum() < 0.35 * len(px)


def test_border_kept_free_integer_unique_and_finite():
    img = textured()
    for border in (DEFAULT_BORDER, 20):
        px = select_points(img, target=800, border=border)
        h, w = img.shape
        assert np.all(np.isfinite(px))
        assert np.all(px == np.round(px))
        assert px[:, 0].min() >= border and px[:, 0].max() <= w - 1 - border
        assert px[:, 1].min() >= border and px[:, 1].max() <= h - 1 - border
        assert len(np.unique(px, axis=0)) == len(px)


def test_low_texture_region_still_gets_points_but_fewer():
    img = textured()
    # right half: same texture at 5 % contrast (weak but present)
    img[:, 160:] = 128 + 0.05 * (img[:, 160:] - 128)
    px = select_points(img, target=1000)
    weak = px[:, 0] >= 160
    assert weak.sum() >= 30                       # the coarser cell levels reach the weak half
    assert weak.sum() < (~weak).sum()             # ... but the strong half dominates
    # picks in the strong half are high-gradient pixels: above the block threshold
    g = gradient_magnitude(img)
    t = block_gradient_thresholds(g)
    strong = px[~weak].astype(int)
    assert np.mean(g[strong[:, 1], strong[:, 0]] > t[strong[:, 1], strong[:, 0]]) > 0.9


def test_flat_image_gives_no_points():
    px = select_points(np.full((100, 120), 77, dtype=np.uint8), target=100)
    assert px.shape == (0, 2)


def test_threshold_map_is_block_median_plus_offset():
    g = np.zeros((64, 64), dtype=np.float32)
    g[:32, :32] = 10.0
    t = block_gradient_thresholds(g, block=32, threshold_offset=7.0)
    # block (0,0) has median 10, all others 0; 3x3 smoothing averages the 4 blocks -> 2.5 + 7
    assert t.shape == g.shape
    np.testing.assert_allclose(t, 2.5 + 7.0)


def test_deterministic_and_sorted():
    img = textured()
    a = select_points(img, target=500, seed=3)
    b = select_points(img, target=500, seed=3)
    np.testing.assert_array_equal(a, b)
    order = np.lexsort((a[:, 0], a[:, 1]))
    np.testing.assert_array_equal(order, np.arange(len(a)))


@pytest.mark.parametrize("kwargs", [dict(target=0), dict(border=200), dict(border=-1), dict(downweight=0.0)])
def test_bad_arguments_raise(kwargs):
    with pytest.raises(InputError):
        select_points(textured(), **kwargs)


def test_nan_image_raises():
    img = textured()
    img[5, 5] = np.nan
    with pytest.raises(InputError):
        select_points(img)


def test_kitti_frame_spread(shared_data):
    cv2 = pytest.importorskip("cv2")
    path = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1" / "image_l" / "000000.png"
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, path
    px = select_points(img, target=2000)
    assert 1800 <= len(px) <= 2000
    h, w = img.shape
    hist, _, _ = np.histogram2d(px[:, 0], px[:, 1], bins=[4, 2], range=[[0, w], [0, h]])
    assert hist.min() > 0.05 * len(px)            # every one of 8 image regions gets points
