"""The ground-truth check of benchmarks/frontend_middlebury.py on a synthetic pair whose ground
truth is off by a known amount: the images' shift from it must be recovered."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.frontend_middlebury import ground_truth_shift


def _texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A smooth, band-limited texture (grey levels) with gradients in every direction."""
    return (128 + 40 * np.sin(0.35 * x + 0.15 * y) + 30 * np.sin(0.2 * x - 0.45 * y + 1.0)
            + 20 * np.cos(0.3 * x + 0.3 * y + 2.0)).astype(np.float32)


@pytest.mark.parametrize("vertical_offset", [0.0, 0.2])
def test_ground_truth_shift_recovers_a_known_offset(vertical_offset: float) -> None:
    h, w, disp, gt_error = 60, 90, 5.3, 0.1
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    left = _texture(x, y)
    right = _texture(x + disp, y - vertical_offset)  # right(u - disp, v + dy) = left(u, v)
    gt = np.full((h, w), disp + gt_error)
    px = np.array([[u, v] for v in range(15, 45, 6) for u in range(20, 80, 7)], dtype=np.float64)
    shift = ground_truth_shift(left, right, gt, px, vertical=vertical_offset != 0.0)
    assert np.all(np.isfinite(shift))
    assert np.median(shift) == pytest.approx(-gt_error, abs=0.01)


def test_ground_truth_shift_is_nan_outside_the_image_or_ground_truth() -> None:
    y, x = np.mgrid[0:40, 0:40].astype(np.float64)
    img = _texture(x, y)
    gt = np.zeros((40, 40))
    gt[20, 20] = np.inf
    shift = ground_truth_shift(img, img, gt, np.array([[1.0, 20.0], [21.0, 21.0], [30.0, 10.0]]))
    assert np.isnan(shift[0]) and np.isnan(shift[1]) and abs(shift[2]) < 0.02
