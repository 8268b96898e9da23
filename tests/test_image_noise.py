"""The noise of an image from the image alone (gtvo/frontend/image_noise.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gtvo.frontend.image_noise import image_noise_sigma


def _texture(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (120, 160)).astype(np.float32), (0, 0), 2.0)
    return (20 + 210 * (img - img.min()) / (img.max() - img.min())).astype(np.float32)


@pytest.mark.parametrize("sigma", [1.0, 2.0, 4.0, 8.0])
def test_the_estimate_finds_the_noise_added_to_a_textured_image(sigma):
    img = _texture()
    noisy = img + np.random.default_rng(1).normal(0, sigma, img.shape).astype(np.float32)
    assert image_noise_sigma(noisy) == pytest.approx(sigma, rel=0.3)


def test_a_smooth_texture_alone_has_almost_no_noise():
    assert image_noise_sigma(_texture()) < 0.5


def test_a_too_small_or_colour_image_is_refused():
    with pytest.raises(ValueError):
        image_noise_sigma(np.zeros((2, 10), dtype=np.float32))
    with pytest.raises(ValueError):
        image_noise_sigma(np.zeros((10, 10, 3), dtype=np.float32))


def _noise_numpy(img: np.ndarray) -> float:
    """The numpy form of image_noise_sigma (its compiled passes' reference)."""
    from gtvo.frontend.image_noise import NOISE_MASK  # noqa: PLC0415

    r = np.abs(cv2.filter2D(img, -1, NOISE_MASK, borderType=cv2.BORDER_REFLECT)[1:-1, 1:-1])
    g = np.abs(img[1:-1, 2:] - img[1:-1, :-2]) + np.abs(img[2:, 1:-1] - img[:-2, 1:-1])
    smooth = g <= np.partition(g.ravel(), g.size // 2)[g.size // 2]
    return float(np.sqrt(np.pi / 2) * np.mean(r[smooth]) / 6.0)


@pytest.mark.parametrize("case", ["texture", "whole levels", "3x3", "narrow", "flat", "infinity", "nan"])
def test_the_estimate_equals_its_numpy_form_to_the_bit(case):
    """The compiled gradient and selection give numpy's value exactly (ties at the median, a flat
    image, an infinite or a NaN pixel included)."""
    rng = np.random.default_rng(5)
    img = {"texture": _texture() + rng.normal(0, 2, (120, 160)).astype(np.float32),
           "whole levels": np.round(_texture() + rng.normal(0, 2, (120, 160))).astype(np.float32),
           "3x3": rng.random((3, 3)).astype(np.float32), "narrow": (rng.random((40, 7)) * 255).astype(np.float32),
           "flat": np.full((9, 11), 7.0, dtype=np.float32), "infinity": _texture(), "nan": _texture()}[case]
    if case in ("infinity", "nan"):
        img[5, 6] = np.inf if case == "infinity" else np.nan
    got, ref = image_noise_sigma(img), _noise_numpy(img)
    assert got == ref or (np.isnan(got) and np.isnan(ref))
