"""Compact gradient images (factors.compact_image): the grey levels alone between uses, samples
bit-identical to the full image's, packed records held in a bounded cache; the window keeps the
keyframes that leave it in this form for the whole-log refinement."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.compact_image import CompactGradientImage, PackedCache, compact_image, packed_cache_budget
from factors.photometric import GradientImage, photometric_residuals, sample_host
from gtvo.datasets.synthetic import make_synthetic_sequence
from gtvo.window import SlidingWindowOptimizer, WindowConfig
from tests._factors_synthetic import small_camera
from tests.test_window import _keyframes


def _points(rng, w, h, n=500):
    return rng.uniform(-3, w + 3, n), rng.uniform(-3, h + 3, n)


@pytest.mark.parametrize("whole,clip", [(True, (0.0, 255.0)), (False, (0.0, 255.0)), (False, None), (True, (10.0, 240.0))])
def test_samples_are_bit_identical_to_the_full_image(whole, clip):
    rng = np.random.default_rng(1)
    img = rng.uniform(-5, 260, (40, 60))
    img = np.clip(np.rint(img), 0, 255) if whole else img
    full = GradientImage(img, clip_range=clip)
    small = CompactGradientImage(full, PackedCache())
    assert small.nbytes == (img.size if whole else 4 * img.size)  # uint8 only when whole grey levels
    u, v = _points(rng, 60, 40)
    a, b = full.sample(u, v), small.sample(u, v)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.array_equal(full.stack, small.stack) and np.array_equal(full.image, small.image)
    assert small.has_clipped == full.has_clipped and isinstance(small, GradientImage)


def test_the_compiled_kernel_gives_the_same_residuals_on_a_compact_target():
    rng = np.random.default_rng(2)
    cam = small_camera()
    host, target = (GradientImage(np.rint(rng.uniform(0, 255, (cam.height, cam.width)))) for _ in range(2))
    px = np.c_[rng.uniform(20, cam.width - 20, 50), rng.uniform(20, cam.height - 20, 50)]
    d = rng.uniform(0.3, 1.0, 50)
    Ih, hv = sample_host(host, px)
    T = gtsam.Pose3(gtsam.Rot3.Expmap(np.r_[0.01, -0.02, 0.005]), np.r_[0.05, 0.0, 0.02])
    a = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), T, target)
    b = photometric_residuals(cam, Ih, hv, px, d, gtsam.Pose3(), T, compact_image(target, PackedCache()))
    for name in ("residual", "valid", "J_depth", "J_host", "J_target"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_the_cache_keeps_at_most_its_budget_and_packs_again_the_same():
    rng = np.random.default_rng(3)
    fulls = [GradientImage(rng.uniform(1, 254, (30, 40))) for _ in range(3)]
    record_bytes = 30 * 40 * 16
    cache = PackedCache(max_bytes=2 * record_bytes)
    smalls = [CompactGradientImage(f, cache) for f in fulls]
    u, v = _points(rng, 40, 30)
    first = smalls[0].sample(u, v)
    smalls[1].sample(u, v)
    smalls[0].sample(u, v)  # the most recent now: smalls[1] goes first
    smalls[2].sample(u, v)
    assert cache.bytes <= cache.max_bytes and cache.packs == 3
    assert smalls[1]._records is None and smalls[0]._records is not None
    again = smalls[1].sample(u, v)
    assert cache.packs == 4 and np.array_equal(again[0], fulls[1].sample(u, v)[0])
    assert np.array_equal(smalls[0].sample(u, v)[0], first[0])


def test_the_window_keeps_the_keyframes_that_leave_with_compact_images():
    seq = make_synthetic_sequence(8, width=160, height=120, step_m=0.1)
    kfs = _keyframes(seq, [0, 1, 2, 3, 4], points=60)
    window = SlidingWindowOptimizer(seq.camera.left, seq.camera.baseline, WindowConfig(size=3, marginalize=False))
    window.retain_keyframes = True
    for kf in kfs:
        window.add_keyframe(kf)
    every = window.every_keyframe()
    assert [k.index for k in every] == [0, 1, 2, 3, 4]
    assert all(isinstance(k.image, CompactGradientImage) and isinstance(k.right, CompactGradientImage)
               for k in window.retired)
    assert not any(isinstance(k.image, CompactGradientImage) for k in window.keyframes)
    u, v = np.array([10.5, 80.25]), np.array([20.75, 60.5])
    for k, src in zip(window.retired, kfs):
        assert np.array_equal(k.image.sample(u, v)[0], src.image.sample(u, v)[0])
        assert np.array_equal(k.inverse_depth, src.inverse_depth) and k.pose.equals(src.pose, 0)


def test_a_budget_block_holds_more_and_gives_it_back():
    rng = np.random.default_rng(4)
    cache = PackedCache(max_bytes=0)
    smalls = [CompactGradientImage(GradientImage(rng.uniform(1, 254, (20, 30))), cache) for _ in range(3)]
    with packed_cache_budget(10 * 20 * 30 * 16, cache):
        for s in smalls:
            s.sample(np.array([5.5]), np.array([6.5]))
        assert cache.bytes == 3 * 20 * 30 * 16 and cache.packs == 3
    assert cache.max_bytes == 0 and cache.bytes == 0 and all(s._records is None for s in smalls)


def test_a_pickled_compact_image_carries_its_grey_levels_only_and_samples_the_same():
    """A parallel window's keyframes come back from its worker pickled: no packed records, no cache."""
    import pickle  # noqa: PLC0415

    from factors.compact_image import SHARED_PACKED_CACHE  # noqa: PLC0415

    rng = np.random.default_rng(5)
    full = GradientImage(np.rint(rng.uniform(0, 255, (40, 60))), clip_range=(0.0, 255.0))
    small = CompactGradientImage(full, PackedCache())
    u, v = _points(rng, 60, 40)
    before = small.sample(u, v)  # its records packed and held by its cache
    data = pickle.dumps(small)
    assert len(data) < 40 * 60 + 1000  # the uint8 grey levels and the flags, not the 16-byte records
    back = pickle.loads(data)
    assert back._records is None and back._cache is SHARED_PACKED_CACHE
    after = back.sample(u, v)
    assert np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])
    assert back.has_clipped == small.has_clipped and back.clip_range == small.clip_range
