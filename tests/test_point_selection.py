import numpy as np
import pytest
from numpy.typing import NDArray

from gtvo.errors import InputError
from gtvo.frontend import (DEFAULT_BORDER, PointSelectionConfig, block_gradient_thresholds, gradient_magnitude,
                           select_points)
from gtvo.frontend._compiled import block_medians, pick_cells

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
        px = select_points(img, 800, PointSelectionConfig(border=border))
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
    a = select_points(img, 500, PointSelectionConfig(seed=3))
    b = select_points(img, 500, PointSelectionConfig(seed=3))
    np.testing.assert_array_equal(a, b)
    order = np.lexsort((a[:, 0], a[:, 1]))
    np.testing.assert_array_equal(order, np.arange(len(a)))


@pytest.mark.parametrize("target,kwargs", [(0, {}), (2000, dict(border=200)), (2000, dict(border=-1)),
                                           (2000, dict(downweight=0.0))])
def test_bad_arguments_raise(target, kwargs):
    with pytest.raises(InputError):
        select_points(textured(), target, PointSelectionConfig(**kwargs))


def test_nan_image_raises():
    img = textured()
    img[5, 5] = np.nan
    with pytest.raises(InputError):
        select_points(img)


def _kitti_left(shared_data, name: str) -> np.ndarray:
    """A left image of KITTI_sequence_1, grey (skips without OpenCV)."""
    cv2 = pytest.importorskip("cv2")
    path = shared_data / "kitti_stereo_sample" / "KITTI_sequence_1" / "image_l" / name
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, path
    return img


def test_kitti_frame_spread(shared_data):
    img = _kitti_left(shared_data, "000000.png")
    px = select_points(img, target=2000)
    assert 1800 <= len(px) <= 2000
    h, w = img.shape
    hist, _, _ = np.histogram2d(px[:, 0], px[:, 1], bins=[4, 2], range=[[0, w], [0, h]])
    assert hist.min() > 0.05 * len(px)            # every one of 8 image regions gets points


# The numpy form of step 3 that gtvo.frontend._compiled.pick_cells replaced: the reference.
def _pad_to_multiple(a: NDArray, m: int, fill: float) -> NDArray:
    h, w = a.shape
    ph, pw = (-h) % m, (-w) % m
    if ph == 0 and pw == 0:
        return a
    return np.pad(a, ((0, ph), (0, pw)), constant_values=fill)


def _pick_hierarchical(score: NDArray, thr: NDArray, eligible: NDArray, cell: int, levels: int,
                       downweight: float) -> NDArray[np.bool_]:
    """Boolean map of picks for one cell size (the 3-level rule of step 3)."""
    h, w = score.shape
    picked = np.zeros((h, w), dtype=bool)
    for lvl in range(levels):
        c = min(cell * (2 ** lvl), max(h, w, cell))  # a cell larger than the image is the whole image
        ok = eligible & (score > thr * (downweight ** lvl))
        masked = _pad_to_multiple(np.where(ok, score, -1.0).astype(np.float32), c, -1.0)
        have = _pad_to_multiple(picked, c, False)
        nby, nbx = masked.shape[0] // c, masked.shape[1] // c
        cells = masked.reshape(nby, c, nbx, c).transpose(0, 2, 1, 3).reshape(nby, nbx, c * c)
        has_pick = have.reshape(nby, c, nbx, c).any(axis=(1, 3))
        idx = np.argmax(cells, axis=-1)
        best = np.take_along_axis(cells, idx[..., None], axis=-1)[..., 0]
        take = (best >= 0) & ~has_pick
        by, bx = np.nonzero(take)
        k = idx[by, bx]
        picked[by * c + k // c, bx * c + k % c] = True
    return picked


@pytest.mark.slow
@pytest.mark.parametrize("shape,cell,border", [((240, 320), 5, DEFAULT_BORDER), ((97, 131), 3, 4), ((370, 1226), 11, 8),
                                               ((64, 64), 1, 0), ((50, 70), 40, 2)])
def test_compiled_cell_pick_equals_the_numpy_rule(shape, cell, border):
    """pick_cells against the numpy rule: same picks, pixel for pixel (ties included: a
    quantised score has many equal maxima per cell)."""
    img = textured(*shape, seed=sum(shape))
    for score in (gradient_magnitude(img), np.floor(gradient_magnitude(img) / 8.0).astype(np.float32)):
        thr = block_gradient_thresholds(score, 32, 7.0 if score.max() > 20 else 0.5)
        eligible = np.zeros(shape, dtype=bool)
        eligible[border:shape[0] - border, border:shape[1] - border] = True
        for levels, downweight in ((3, 0.75), (1, 1.0), (4, 0.5), (70, 0.9)):  # 70: 2^69 cells, no overflow
            ref = _pick_hierarchical(score, thr, eligible, cell, levels, downweight)
            factors = np.array([downweight ** lvl for lvl in range(levels)], dtype=np.float32)
            assert ref.any()
            # the thresholds per pixel (block 1) and per 32x32 block (as select_points passes them)
            assert np.array_equal(pick_cells(score, thr, 1, border, cell, factors), np.flatnonzero(ref))
            grid = np.ascontiguousarray(thr[::32, ::32])
            assert np.array_equal(pick_cells(score, grid, 32, border, cell, factors), np.flatnonzero(ref))


@pytest.mark.parametrize("kind", ["uniform", "integers", "constant", "exponential", "kitti-like", "signed", "zeros",
                                  "two-values", "wide"])
@pytest.mark.parametrize("block", [1, 2, 7, 32])
def test_compiled_block_medians_equal_numpy_median(kind, block):
    """block_medians against ``np.median`` over the transposed blocks (the numpy form it replaced):
    equal bit for bit, ties, constant blocks and odd/even counts included."""
    rng = np.random.default_rng(block)
    shape = (3 * block, 5 * block)
    g = {"uniform": lambda: rng.random(shape) * 300, "integers": lambda: np.round(rng.random(shape) * 20),
         "constant": lambda: np.full(shape, 3.5), "exponential": lambda: rng.exponential(5.0, shape),
         "kitti-like": lambda: np.abs(rng.normal(0, 1, shape)) ** 3,
         "signed": lambda: rng.normal(0, 1, shape),  # negative values: compared as floats, not as bits
         "zeros": lambda: np.where(rng.random(shape) < 0.6, 0.0, rng.exponential(5.0, shape)),
         "two-values": lambda: np.where(rng.random(shape) < 0.5, 0.25, 1e6),  # the middle bins hold all
         "wide": lambda: rng.exponential(1.0, shape) * 10.0 ** rng.integers(-30, 30, shape)}[kind]().astype(np.float32)
    cells = g.reshape(3, block, 5, block).transpose(0, 2, 1, 3).reshape(3, 5, block * block)
    assert np.array_equal(block_medians(g, block), np.median(cells, axis=-1))


def _magnitude_numpy(img):
    """The numpy form of gradient_magnitude (the reference of the compiled gradient_norm)."""
    from gtvo.core.image import image_gradients  # noqa: PLC0415

    gx, gy = image_gradients(np.asarray(img, dtype=np.float32))
    return np.sqrt(gx * gx + gy * gy)


@pytest.mark.parametrize("shape", [(2, 2), (2, 9), (9, 2), (3, 5), (97, 131), (240, 320)])
@pytest.mark.parametrize("kind", ["texture", "uint8", "wide"])
def test_compiled_gradient_magnitude_equals_the_numpy_form(shape, kind):
    """One compiled pass gives np.sqrt(gx^2 + gy^2) of image_gradients bit for bit, borders included."""
    rng = np.random.default_rng(sum(shape))
    img = {"texture": lambda: textured(*shape, seed=sum(shape)),
           "uint8": lambda: rng.integers(0, 256, shape).astype(np.uint8),
           "wide": lambda: (rng.standard_normal(shape) * 1e4).astype(np.float32)}[kind]()
    got = gradient_magnitude(img)
    assert got.dtype == np.float32 and got.shape == shape
    assert np.array_equal(got, _magnitude_numpy(img))


@pytest.mark.realdata
def test_compiled_gradient_magnitude_equals_the_numpy_form_on_kitti(shared_data):
    img = _kitti_left(shared_data, "000010.png")
    assert np.array_equal(gradient_magnitude(img), _magnitude_numpy(img))


@pytest.mark.realdata
@pytest.mark.parametrize("cell", [7, 38, 45])
def test_compiled_cell_pick_equals_the_numpy_rule_on_kitti(shared_data, cell):
    """pick_cells on a KITTI frame (the cell sizes of a 300- and a 2000-point selection)."""
    img = _kitti_left(shared_data, "000020.png")
    score = gradient_magnitude(img)
    thr = block_gradient_thresholds(score)
    eligible = np.zeros(score.shape, dtype=bool)
    eligible[DEFAULT_BORDER:-DEFAULT_BORDER, DEFAULT_BORDER:-DEFAULT_BORDER] = True
    factors = np.array([0.75 ** lvl for lvl in range(3)], dtype=np.float32)
    got = pick_cells(score, np.ascontiguousarray(thr[::32, ::32]), 32, DEFAULT_BORDER, cell, factors)
    assert np.array_equal(got, np.flatnonzero(_pick_hierarchical(score, thr, eligible, cell, 3, 0.75)))


def _thresholds_numpy(grad_mag, block, threshold_offset):
    """block_gradient_thresholds as numpy made it (the reference of block_medians on partial blocks
    and of smooth_block_thresholds): np.median of each block of the mirror-padded magnitude, then
    the 3x3 nanmean over the NaN-padded grid, the offset, np.repeat."""
    g = np.asarray(grad_mag, dtype=np.float32)
    h, w = g.shape
    padded = np.pad(g, ((0, (-h) % block), (0, (-w) % block)), mode="symmetric")
    nby, nbx = padded.shape[0] // block, padded.shape[1] // block
    cells = padded.reshape(nby, block, nbx, block).transpose(0, 2, 1, 3).reshape(nby, nbx, block * block)
    return _smooth_and_spread_numpy(np.median(cells, axis=-1), block, h, w, threshold_offset)


def _smooth_and_spread_numpy(med, block, h, w, threshold_offset):
    nby, nbx = med.shape
    p = np.pad(med, 1, constant_values=np.nan)
    stack = np.stack([p[i:i + nby, j:j + nbx] for i in range(3) for j in range(3)])
    smooth = np.nanmean(stack, axis=0) + float(threshold_offset)
    full = np.repeat(np.repeat(smooth, block, axis=0), block, axis=1)
    return full[:h, :w].astype(np.float32)


@pytest.mark.parametrize("shape,block", [((240, 320), 32), ((97, 131), 32), ((97, 131), 7), ((33, 65), 32),
                                         ((5, 3), 2), ((1, 1), 1), ((31, 31), 32)])
@pytest.mark.parametrize("kind", ["texture", "random", "wide"])
def test_compiled_thresholds_equal_the_numpy_form(shape, block, kind):
    """The smoothing and spreading of the block medians in one compiled pass: the numpy form's
    float32 values bit for bit (odd sizes, partial blocks, one block, random magnitudes whose
    float32 sums depend on their order)."""
    rng = np.random.default_rng(sum(shape) + block)
    g = {"texture": lambda: gradient_magnitude(np.pad(textured(max(shape[0], 3), max(shape[1], 3)), 0))[
             :shape[0], :shape[1]],
         "random": lambda: rng.exponential(5.0, shape),
         "wide": lambda: rng.exponential(1.0, shape) * 10.0 ** rng.integers(-6, 7, shape)}[kind]()
    for offset in (7.0, 0.0, 1e-3, 123.456):
        got = block_gradient_thresholds(g, block, offset)
        assert got.dtype == np.float32 and got.shape == shape
        assert np.array_equal(got, _thresholds_numpy(g, block, offset))


def test_compiled_smoothing_skips_nan_medians_as_nanmean():
    from gtvo.frontend._compiled import smooth_block_thresholds  # noqa: PLC0415

    rng = np.random.default_rng(4)
    med = rng.exponential(5.0, (6, 9)).astype(np.float32)
    med[rng.random(med.shape) < 0.3] = np.nan
    med[0, 0] = med[0, 1] = med[1, 0] = med[1, 1] = np.nan  # the corner block: no neighbour at all
    with np.errstate(all="ignore"), pytest.warns(RuntimeWarning):
        ref = _smooth_and_spread_numpy(med, 4, 23, 35, 7.0)
    got = np.repeat(np.repeat(smooth_block_thresholds(med, np.float32(7.0)), 4, axis=0), 4, axis=1)[:23, :35]
    assert np.array_equal(got, ref, equal_nan=True) and np.isnan(got[0, 0])


@pytest.mark.realdata
def test_compiled_thresholds_equal_the_numpy_form_on_kitti(shared_data):
    for name in ("000000.png", "000030.png"):
        g = gradient_magnitude(_kitti_left(shared_data, name))
        assert np.array_equal(block_gradient_thresholds(g), _thresholds_numpy(g, 32, 7.0))


@pytest.mark.realdata
def test_compiled_block_medians_equal_numpy_median_on_kitti(shared_data):
    for name in ("000000.png", "000040.png"):
        g = gradient_magnitude(_kitti_left(shared_data, name))[:352, :1216]  # 11 x 38 blocks of 32
        cells = g.reshape(11, 32, 38, 32).transpose(0, 2, 1, 3).reshape(11, 38, 32 * 32)
        assert np.array_equal(block_medians(np.ascontiguousarray(g), 32), np.median(cells, axis=-1))


@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (5, 40), (33, 65), (97, 131)])
@pytest.mark.parametrize("block", [2, 7, 32])
def test_compiled_block_medians_mirror_partial_blocks_as_np_pad(shape, block):
    """Partial blocks at the bottom / right are completed as np.pad(mode="symmetric") does (several
    reflections when the image is smaller than the missing part), without the padded copy."""
    g = np.random.default_rng(sum(shape) + block).exponential(5.0, shape).astype(np.float32)
    padded = np.pad(g, ((0, (-shape[0]) % block), (0, (-shape[1]) % block)), mode="symmetric")
    nby, nbx = padded.shape[0] // block, padded.shape[1] // block
    cells = padded.reshape(nby, block, nbx, block).transpose(0, 2, 1, 3).reshape(nby, nbx, block * block)
    assert np.array_equal(block_medians(g, block), np.median(cells, axis=-1))


def test_compiled_block_medians_of_blocks_with_nan_or_infinity_are_np_median():
    """A NaN makes the block's median NaN and infinities are ordered values, as np.median has them
    (never an index out of the histogram)."""
    rng = np.random.default_rng(3)
    for block in (3, 8):
        g = rng.exponential(5.0, (4 * block, 5 * block)).astype(np.float32)
        g[0, 0] = np.nan
        g[block, block + 1] = -np.nan
        g[2 * block:3 * block, :2 * block] = np.inf  # a whole block (and half of the next) infinite
        g[3 * block + 1, 3 * block] = -np.inf
        g[3 * block + 2, 4 * block] = np.inf
        cells = g.reshape(4, block, 5, block).transpose(0, 2, 1, 3).reshape(4, 5, block * block)
        assert np.array_equal(block_medians(g, block), np.median(cells, axis=-1), equal_nan=True)
