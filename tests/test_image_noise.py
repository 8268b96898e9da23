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
